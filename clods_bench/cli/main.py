"""The `clods-bench` command line: list, data, run, tables, report, reproduce, compare, seed-spread, bench."""

from __future__ import annotations

import argparse
import contextlib
import copy
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Sequence

from rich.console import Console
from rich.table import Table

from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    from clods_bench.benchmark.core.config import RunConfig

console = Console()
err_console = Console(stderr=True, soft_wrap=True)


def _add_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="ci", help="built-in preset: ci, small, paper (default: ci)")
    p.add_argument("--config", type=Path, help="YAML file merged over the preset (may name `preset:`)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="override a config field, e.g. data.num_train=8")
    p.add_argument("--scene", help="scene name (same as --set data.scene=NAME)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="clods-bench", description="Benchmark for learning cloth dynamics from multi-view video.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument(
        "--no-deterministic", action="store_true",
        help="use the host CPU's own (fastest) floating-point paths; by default every computing command runs with exact "
             "numerics, which give the same bits on every x86-64 CPU with AVX2 (same as CLODS_BENCH_DETERMINISTIC=0; see "
             "`clods-bench numerics`)",
    )  # fmt: skip
    parser.add_argument(
        "--strict-plugins", action="store_true",
        help="stop with an error when an installed plugin fails to load (by default it is named in a warning and left "
             "out); same as CLODS_BENCH_STRICT_PLUGINS=1, which CI sets",
    )  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("numerics", help="deterministic mode: the pinned floating-point paths, and those this process uses")
    p.add_argument("--export", action="store_true", help="print the pins as shell `export` lines (for Python code that imports numpy first)")
    p.add_argument("--probe", action="store_true",
                   help="also run four tiny fits (graph net, video predictor, renderer fit, extraction) and print their digests: "
                        "two machines in deterministic mode print the same ones")  # fmt: skip
    p.set_defaults(func=cmd_numerics)

    p = sub.add_parser("list", help="plugins, scenes, tasks and presets")
    p.set_defaults(func=cmd_list)

    data = sub.add_parser("data", help="generate, import and export datasets")
    dsub = data.add_subparsers(dest="data_command", required=True)
    p = dsub.add_parser("generate", help="simulate and render a scene's dataset (resumable)")
    _add_config_args(p)
    p.add_argument("--force", action="store_true", help="delete an existing dataset with these settings first")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="generate the trajectories here (default) or as Ray tasks")
    p.add_argument("--jobs", type=int, help="local executor: trajectories generated in this many worker processes (default: one per core)")
    p.add_argument("--ray-address", help="Ray cluster address (default: start a local one)")
    p.set_defaults(func=cmd_data_generate)
    p = dsub.add_parser("convert", help="convert a dataset of an older clods-bench (store schema 1, raw .npy frames) in place")
    p.add_argument("root", type=Path, help="a dataset directory, or a data root holding dataset directories")
    p.set_defaults(func=cmd_data_convert)
    p = dsub.add_parser("digest", help="content digests of a dataset (arrays, not files): did two machines generate the same data?")
    p.add_argument("root", type=Path, help="a dataset directory")
    p.add_argument("--frames", action="store_true", help="also digest the decoded images (reads every frame)")
    p.add_argument("--out", type=Path, help="write the digests to this JSON file")
    p.add_argument("--against", type=Path, help="a digest JSON from another machine: exit 1 naming each trajectory that differs and its first frame")
    p.set_defaults(func=cmd_data_digest)
    p = dsub.add_parser("import-flagsimple", help="convert the real FLAGSIMPLE release (meta.json + TFRecord)")
    p.add_argument("source", type=Path, help="directory with meta.json and <split>.tfrecord")
    p.add_argument("--split", default="train")
    p.add_argument("--limit", type=int, default=None, help="number of trajectories to convert")
    p.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    p.set_defaults(func=cmd_data_import)
    p = dsub.add_parser("export", help="write a stored trajectory as an OBJ/PLY sequence, or the dataset in the NeRF layout")
    _add_config_args(p)
    p.add_argument("--traj", type=int, nargs="+", default=None,
                   help="trajectories (default: 0 for obj/ply, every one for nerf)")  # fmt: skip
    p.add_argument("--format", choices=("obj", "ply", "nerf"), default="obj",
                   help="obj/ply: one mesh file per frame; nerf: per trajectory a transforms.json (camera-to-world, OpenGL "
                        "axes) and a PNG folder per camera")  # fmt: skip
    p.add_argument("--meshes", choices=("obj", "ply", "none"), default="none", help="nerf: also write the meshes per frame")
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(func=cmd_data_export)
    p = dsub.add_parser("export-meshes", help="write the meshes a run saved (seed_N/*.npz: initial, extracted, rollout) as OBJ/PLY sequences")
    p.add_argument("sample", type=Path, help="a run's mesh sample, e.g. runs/cdg/<label>/<id>/seed_0/extraction_meshes.npz")
    p.add_argument("--format", choices=("obj", "ply"), default="obj")
    p.add_argument("--out", type=Path, required=True, help="one folder per sequence (and truth/) is written here")
    p.set_defaults(func=cmd_data_export_meshes)
    p = dsub.add_parser("import-video", help="a dataset from your own multi-view captures (image folders or videos + transforms.json)")
    p.add_argument("transforms", type=Path, nargs="+", help="one transforms.json per capture (each becomes one trajectory)")
    p.add_argument("--out", type=Path, required=True, help="dataset directory to write (run on it with --set data.path=DIR)")
    p.add_argument("--masks", help="folder (relative to each transforms.json) with a subfolder of mask images per camera")
    p.add_argument("--meshes", help="folder (relative to each transforms.json) with one OBJ/PLY per frame (+ topology.npz)")
    p.add_argument("--num-views-test", type=int, help="held-out cameras for NVS (default: transforms.json's, else 1 per 6 cameras)")
    p.add_argument("--interp-steps", type=int, help="last interpolation frame (default: transforms.json's, else 3/4 of the frames)")
    p.add_argument("--fps", type=float, help="frame rate when neither transforms.json nor the videos give one")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out (only once the import has succeeded)")
    p.set_defaults(func=cmd_data_import_video)

    p = sub.add_parser("run", help="run a task: cdg, nvs, stability, dvc, ...")
    p.add_argument("task", help="task name")
    p.add_argument("--sim", help="simulator plugin")
    p.add_argument("--renderer", help="renderer plugin")
    p.add_argument("--predictor", help="video-predictor plugin (dvc task baselines: copylast, simvp, tau, mau, mmvp)")
    p.add_argument("--label", help="row label in the tables")
    p.add_argument("--train-subset", choices=("all", "first_half"), help="training trajectories: all (MGN) or first half (MGN*)")
    p.add_argument("--seeds", type=int, nargs="+", help="seeds (default from the preset)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="run the seeds here (default) or as Ray tasks")
    p.add_argument("--jobs", type=int,
                   help="local executor: seeds run in this many worker processes (default: one per core, at most one per seed; "
                        "the numbers are the same for any count)")  # fmt: skip
    p.add_argument("--ray-address", help="Ray cluster address (default: start a local one)")
    _add_config_args(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("tables", help="paper-layout tables (markdown, LaTeX, CSV) from run records")
    p.add_argument("--runs", type=Path, nargs="+", default=[Path("runs")],
                   help="runs folder(s): the records of several (other machines, committed records) make one table")
    p.add_argument("--out", type=Path, default=Path("tables"))
    p.add_argument("--task", default="all", help="cdg, nvs, stability, dvc, dvc_multi, extract, or all (every task with records; default)")
    p.set_defaults(func=cmd_tables)

    p = sub.add_parser("report", help="HTML report (report/index.html): every table, error-vs-time and rollout plots, NVS grids, DVC media")
    p.add_argument("--runs", type=Path, default=Path("runs"))
    p.add_argument("--out", type=Path, default=Path("report"))
    p.add_argument("--metric", default="unviewed/extrap/d_avg", help="CDG metric on the error axis (group/phase/stat)")
    p.add_argument("--bench", type=Path, default=Path("bench"), help="folder of `bench infer` results shown in the report when present (default bench)")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("reproduce", help="run the paper's tables from the reproduce plan; tables + manifest.json into --out")
    p.add_argument("--preset", default="ci", help="built-in preset: ci, small, paper (default: ci)")
    p.add_argument("--plan", type=Path, help="plan YAML (default: the built-in clods_bench/benchmark/reproduction/plans/reproduce.yaml)")
    p.add_argument("--out", type=Path, help="folder of the tables and manifest (default: results/<preset>)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="run the (run, seed) jobs here (default) or as Ray tasks")
    p.add_argument("--jobs", type=int,
                   help="local executor: (run, seed) jobs run in this many worker processes (default: one per core; the numbers "
                        "are the same for any count)")  # fmt: skip
    p.add_argument("--ray-address", help="Ray cluster address (default: start a local one)")
    p.add_argument("--only", nargs="+", default=[], metavar="TABLE", help="only these table ids of the plan")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="override applied to every run")
    p.add_argument("--check", type=Path, metavar="DIR", help="then compare the fresh CSVs with the committed ones in DIR (exit 1 on a moved number)")
    p.add_argument(
        "--first-seeds",
        type=int,
        metavar="K",
        help="run only the first K seeds of every run (a quicker --check: seed-to-seed std columns are then not compared)",
    )
    p.add_argument(
        "--budget",
        type=float,
        metavar="SECONDS",
        help="local executor: start no job after SECONDS; tables left unfinished are not written (nor checked), the next run resumes them",
    )
    p.add_argument("--dry-run", action="store_true", help="check the plan and list its runs, run nothing")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("compare", help="compare fresh result CSVs with committed ones (tolerance.yaml of the committed folder)")
    p.add_argument("committed", type=Path, help="folder with the committed CSV tables and tolerance.yaml")
    p.add_argument("fresh", type=Path, help="folder with freshly produced CSV tables")
    p.add_argument("--tolerance", type=Path, help="tolerance YAML (default: COMMITTED/tolerance.yaml)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("seed-spread", help="seed-to-seed variation of every metric in the run records (justifies the tolerance)")
    p.add_argument("--runs", type=Path, default=Path("runs"))
    p.add_argument("--task", help="only this task")
    p.add_argument("--csv", type=Path, help="also write the per-metric rows as CSV")
    p.set_defaults(func=cmd_seed_spread)

    p = sub.add_parser("bench", help="speed benchmarks (ratios against a reference measured in the same run)")
    p.add_argument("what", choices=("data", "render", "sim", "stage2", "store", "infer", "video", "determinism"),
                   help="data: cloth solver and ground-truth rasterizer; render: fast CPU splatting vs the torch reference; "
                        "sim: train/inference step time of each simulator vs the physics solver; "
                        "stage2: CloDS stage-2 ms per iteration and per frame at --preset scale, cpu vs the torch reference; "
                        "store: frame store bytes and read speed vs raw .npy; "
                        "infer: ms per frame of CloDS (learned step + SMGS render of every view) vs the traditional pipeline "
                        "(physics solver step + ground-truth rasterizer) at --preset size; "
                        "video: training-step time of each video predictor at --preset size and its preset training time; "
                        "determinism: deterministic mode's cost, MGN and CPU splatting against the host's own paths")  # fmt: skip
    p.add_argument("--preset", default="ci", help="store: the preset whose trajectory 0 is measured; stage2: preset whose data, "
                   "cameras and task_config.clods are used; infer: preset whose mesh, cameras, image size and model sizes are timed (default: ci)")  # fmt: skip
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="store, infer, video: config override, e.g. data.root=DIR or video_config.tau.hid_s=16; sim: sim_config.<name>.<field>=VALUE")
    p.add_argument("--blocks", type=int, default=None,
                   help="store: render only this many chunk-long runs of frames spread through the trajectory (all cameras) "
                        "and extrapolate the bytes (default: every frame)")  # fmt: skip
    p.add_argument("--steps", type=int, default=400, help="data: solver steps to time")
    p.add_argument("--views", type=int, default=None, help="data/render: views to render (default 8); infer: render only this many of "
                   "the preset's cameras (a cap, reported; default all)")  # fmt: skip
    p.add_argument("--size", type=int, default=128, help="render: image side in pixels")
    p.add_argument("--repeats", type=int, default=3, help="render: timed repeats (minimum reported)")
    p.add_argument("--gsplat", action=argparse.BooleanOptionalAction, default=None,
                   help="render: time the gsplat CUDA backend too (default: when gsplat and a GPU are available)")
    p.add_argument("--reference", action=argparse.BooleanOptionalAction, default=True,
                   help="render: time the plain-torch reference (--no-reference at large sizes: its memory grows with pixels)")
    p.add_argument("--sims", nargs="+", default=["mgn", "bsms", "hcmt", "physics"], help="sim: simulators to time")
    p.add_argument("--predictors", nargs="+", default=["simvp", "tau", "mau", "mmvp"], help="video: video predictors to time")
    p.add_argument("--frames", type=int, default=None, help="sim: rollout length in frames (default 12); stage2: frames to extract "
                   "(default 12); infer: frames timed after one untimed frame (default 5)")  # fmt: skip
    p.add_argument("--fit-iterations", type=int, default=None,
                   help="stage2: renderer fit iterations on frame 0 before timing (default 60); infer: the same (default 0: initial parameters)")  # fmt: skip
    p.add_argument("--sim", default="mgn", help="infer: CloDS's learned simulator (default mgn; untrained weights, the preset's size)")
    p.add_argument("--device", default="cpu", help="infer: cpu, or cuda[:N] to render with the gsplat backend on the GPU; sim, video: "
                   "also time each learned simulator or predictor on this device (cpu / device speed-up in one run)")
    p.add_argument("--cpu", action=argparse.BooleanOptionalAction, default=True,
                   help="video: time each predictor on the CPU too (--no-cpu with --device cuda: only the device rows)")
    p.add_argument("--out", type=Path, default=Path("bench"), help="infer: folder of infer_<preset>.json/.csv and infer_time.png (default bench)")
    p.add_argument("--no-progress", action="store_true", help="infer: hide the progress bar")
    p.set_defaults(func=cmd_bench)
    return parser


def _registry():
    from clods_bench.benchmark.core.registry import default_registry

    return default_registry()


def _config(args: argparse.Namespace, **fields):
    from clods_bench.benchmark.core.config import load_config

    overrides = list(args.overrides)
    if getattr(args, "scene", None):
        overrides.insert(0, f"data.scene={args.scene}")
    if getattr(args, "no_progress", False):
        overrides.append("progress=false")
    return load_config(args.preset, args.config, overrides, **fields)


def cmd_list(args: argparse.Namespace) -> int:
    from clods_bench import __version__
    from clods_bench.api_version import API_VERSION
    from clods_bench.benchmark.core.config import preset_description, preset_names
    from clods_bench.benchmark.core.plugin_report import print_problems, source_label

    reg = _registry()
    table = Table(title=f"clods-bench {__version__} (plugin API {API_VERSION}): what is installed")
    for col in ("kind", "name", "description", "from"):
        table.add_column(col)
    for kind in ("task", "simulator", "renderer", "video_predictor", "scene"):
        for name in reg.names(kind):
            table.add_row(kind, name, reg.get(kind, name).description, source_label(reg, kind, name))
    for name in preset_names():
        table.add_row("preset", name, preset_description(name), "built-in")
    console.print(table)
    print_problems(console, reg, tracebacks=args.debug)
    return 0


def cmd_numerics(args: argparse.Namespace) -> int:
    from clods_bench import numerics as dm

    if args.export:
        for key, value in sorted(dm.pins().items()):
            print(f"export {key}='{value}'")  # plain print: no line wrapping, the output is for `eval`
        print(f"export {dm.SWITCH_ENV}=1")
        return 0
    from clods_bench.benchmark.core.determinism import effective_paths

    info = dm.describe()
    console.print(f"mode: {info['mode']} (CPU: {info['cpu']}; pins version {dm.PINS_VERSION}, {dm.pinning.threads()} thread(s) per job)"
                  if dm.active() else f"mode: host paths (CPU: {info['cpu']}); exact numerics are off", highlight=False)  # fmt: skip
    for key, value in sorted((info.get("pins") or {}).items()):
        console.print(f"  {key}={value}", highlight=False, markup=False)
    missing = dm.missing_cpu_features()
    if dm.requested() and missing:
        console.print(f"this CPU lacks {', '.join(missing)}: deterministic runs stop with an error here", highlight=False)
    console.print("in use: " + ", ".join(f"{k}={v}" for k, v in effective_paths().items()), highlight=False)
    if args.probe:
        from clods_bench.benchmark.speed.determinism_probe import probe

        for family, got in probe().items():
            console.print(f"probe {family}: {got['digest']} ({got['seconds']:.1f} s)", highlight=False)
    return 0


def cmd_data_generate(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.running.executors import make_executor
    from clods_bench.datasets.generate import generate

    cfg = _config(args)
    scene = _registry().get("scene", cfg.data.scene)
    from clods_bench.benchmark.running.executors import default_jobs

    jobs = args.jobs or default_jobs()
    executor = None if args.executor == "local" and jobs == 1 else make_executor(args.executor, args.ray_address, jobs)
    store = generate(cfg.data, scene, progress=cfg.progress, force=args.force, executor=executor)
    console.print(f"dataset: {store.root} ({len(store)} trajectories)")
    return 0


def cmd_data_convert(args: argparse.Namespace) -> int:
    from clods_bench.datasets.convert import convert_tree

    for done in convert_tree(args.root):
        if done.already:
            note = f", removed {done.npy_bytes / 1e6:.1f} MB of leftover .npy" if done.npy_bytes else ""
            console.print(f"{done.root}: already in the current layout{note}")
        else:
            ratio = done.npy_bytes / done.stored_bytes if done.stored_bytes else float("nan")
            console.print(f"{done.root}: converted {done.trajectories} trajectories, frames {done.npy_bytes / 1e6:.1f} MB "
                          f"(.npy) -> {done.stored_bytes / 1e6:.1f} MB ({ratio:.1f}x smaller)")  # fmt: skip
    return 0


def cmd_data_digest(args: argparse.Namespace) -> int:
    import json

    from clods_bench.atomic import write_json
    from clods_bench.datasets.digest import compare_digests, dataset_digest
    from clods_bench.datasets.store import DatasetStore

    ours = dataset_digest(DatasetStore.open(args.root), frames=args.frames)
    if args.out:
        write_json(args.out, ours)
    trajs = ours["trajectories"]
    console.print(f"{args.root}: {len(trajs)} trajectories, scene {ours['scene']}" + (f"; digests in {args.out}" if args.out else ""))
    if not args.out and not args.against:
        for key, entry in trajs.items():
            console.print(f"  {key} {entry.get('split')} {entry.get('static', '-')[:16]} "
                          f"last frame {(entry.get('world_pos') or ['-'])[-1]}")  # fmt: skip
    if args.against:
        try:
            theirs = json.loads(Path(args.against).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ClodsError(f"cannot read the digest file: {exc}", where=str(args.against)) from None
        if not isinstance(theirs, dict) or "trajectories" not in theirs:
            raise ClodsError("not a digest file (no 'trajectories')", where=str(args.against), hint="write one with `clods-bench data digest DIR --out FILE`")
        problems = compare_digests(ours, theirs)
        if problems:
            err_console.print(f"{len(problems)} difference(s) against {args.against}:", highlight=False)
            for line in problems:
                err_console.print(f"  {line}", highlight=False)
            return 1
        console.print(f"the same data as {args.against}")
    return 0


def cmd_data_import(args: argparse.Namespace) -> int:
    from clods_bench.datasets.flagsimple import import_flagsimple

    store = import_flagsimple(args.source, args.out, split=args.split, limit=args.limit)
    console.print(f"imported into {store.root} ({len(store)} trajectories)")
    return 0


def cmd_data_export(args: argparse.Namespace) -> int:
    from clods_bench.datasets.meshes import export_sequence
    from clods_bench.datasets.store import DatasetStore

    cfg = _config(args)
    store = DatasetStore.open(cfg.data.dataset_dir())
    if args.format == "nerf":
        from clods_bench.datasets.nerf import export_nerf

        folders = export_nerf(store, args.out, args.meshes, args.traj, store.config.get("num_views_test"), store.config.get("interp_steps"))
        console.print(f"wrote {len(folders)} trajectory folders (transforms.json + PNG per camera and frame) to {args.out}")
        return 0
    if args.meshes != "none":
        raise ClodsError("--meshes applies to --format nerf", where="--meshes", hint="--format obj|ply writes meshes already")
    total = 0
    for traj in args.traj or [0]:
        out = args.out if not args.traj or len(args.traj) == 1 else args.out / f"traj_{traj:04d}"
        total += len(export_sequence(store.load_trajectory(traj), out, args.format))
    console.print(f"wrote {total} {args.format.upper()} files to {args.out}")
    return 0


def cmd_data_export_meshes(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.outputs.mesh_export import export_mesh_sample

    written = export_mesh_sample(args.sample, args.out, args.format)
    for name, paths in written.items():
        console.print(f"{name}: {len(paths)} {args.format.upper()} files in {paths[0].parent if paths else args.out}")
    return 0


def cmd_data_import_video(args: argparse.Namespace) -> int:
    import time

    from clods_bench.datasets.video_import import import_video

    t0 = time.perf_counter()
    store = import_video(args.transforms, args.out, masks=args.masks, meshes=args.meshes, num_views_test=args.num_views_test,
                         interp_steps=args.interp_steps, fps=args.fps, force=args.force)  # fmt: skip
    cfg = store.config
    console.print(f"imported {len(store)} trajectories ({cfg['num_cameras']} cameras, {cfg['num_steps']} frames, "
                  f"{cfg['width']}x{cfg['height']}, meshes: {'yes' if store.has_meshes else 'no'}) into {store.root} "
                  f"in {time.perf_counter() - t0:.1f} s; run on it with --set data.path={store.root}")  # fmt: skip
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.running.records import RECORD_FILE
    from clods_bench.benchmark.running.runner import run_task

    cfg = _config(args, task=args.task, sim=args.sim, renderer=args.renderer, predictor=args.predictor, label=args.label, train_subset=args.train_subset, seeds=args.seeds)
    from clods_bench.benchmark.running.executors import default_jobs, make_executor
    from clods_bench.benchmark.running.seed_jobs import run_configs

    jobs = args.jobs or min(default_jobs(), max(1, len(cfg.seeds)))
    if args.executor == "local" and jobs == 1:
        rdir = run_task(cfg, _registry(), err_console)
    else:
        summary = run_configs([("run", cfg)], make_executor(args.executor, args.ray_address, jobs), _registry(), err_console)
        rdir = Path(summary[0]["record_dir"])
    import json

    rec = json.loads((rdir / RECORD_FILE).read_text())
    table = Table(title=f"{rec['task']} / {rec['label']} / {rec['scene']} / preset {rec['preset']} ({len(rec['seeds'])} seeds)")
    table.add_column("metric")
    table.add_column("mean ± std", justify="right")
    for key, v in sorted(rec["metrics"].items(), key=lambda kv: _metric_order(kv[0])):
        table.add_row(key, _pm(v))
    for key, v in rec["timings"].items():
        table.add_row(f"[dim]{key}[/dim]", _pm(v))
    console.print(table)
    console.print(f"record: {rdir}")
    return 0


def _metric_order(key: str) -> tuple:
    """Sort 'group/phase/stat' keys in the paper's column order."""
    from clods_bench.benchmark.scoring.metrics import GROUPS, PHASES, STATS

    order = {name: i for i, name in enumerate((*GROUPS, *PHASES, *STATS))}
    ranks = [order.get(part, 99) for part in key.split("/")]
    return (*ranks, *[99] * (3 - len(ranks)), key)  # padded: keys of different depths ('psnr', 'all/psnr') compare


def _pm(v: dict) -> str:
    if v["mean"] is None:
        return "n/a"
    return f"{v['mean']:.4g} ± {v['std']:.2g}"


def cmd_tables(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.running.records import iter_records, runs_label
    from clods_bench.benchmark.outputs.tables import write_tables

    if args.task == "all":
        tasks = [t for t in ("cdg", "nvs", "stability", "dvc", "dvc_multi", "extract") if any(True for _ in iter_records(args.runs, t))]
        if not tasks:
            raise ClodsError("no run records found", where=runs_label(args.runs), hint="run e.g. `clods-bench run cdg --sim constvel` first")
    else:
        tasks = [args.task]
    paths = [p for task in tasks for p in write_tables(args.runs, args.out, task)]
    for p in paths:
        if p.suffix == ".md":
            console.print(p.read_text())
    console.print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.outputs.html_report import build_html_report

    paths = build_html_report(args.runs, args.out, args.metric, bench_dir=args.bench)
    console.print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.running.executors import default_jobs
    from clods_bench.benchmark.reproduction.reproduce import build_configs, load_plan, reproduce, run_name, run_overrides

    out = args.out or Path("results") / args.preset
    if args.check is not None and out.resolve() == args.check.resolve():
        raise ClodsError("--check compares fresh tables with committed ones: they cannot be the same folder", where=str(out), hint="write the fresh ones elsewhere with --out")
    overrides = [*args.overrides, *(["progress=false"] if args.no_progress else [])]
    if args.dry_run:
        plan = load_plan(args.plan)
        if args.only:
            plan.runs = [r for r in plan.runs if r.table in args.only]
            plan.tables = [t for t in plan.tables if t.id in args.only]
        registry = _registry()
        runs = build_configs(plan, args.preset, registry, overrides, first_seeds=args.first_seeds)
        table = Table(title=f"reproduce plan, preset {args.preset}: {len(runs)} runs")
        for col in ("table / label", "task", "plugins", "seeds", "done", "overrides"):
            table.add_column(col)
        rdirs = _record_dirs(runs, registry)
        finished = _finished_seeds(runs, rdirs)
        for (run, cfg), done in zip(runs, finished):
            plugins = "+".join(p for p in (cfg.sim, cfg.renderer, getattr(cfg, "predictor", None)) if p)
            table.add_row(run_name(run), run.task, plugins, str(cfg.seeds), ",".join(map(str, done)) or "-", " ".join(run_overrides(run)))
        console.print(table)
        # Rows of one config (a table reusing another's run) share their record: count each (config, seed) once.
        jobs = {(str(rdir), seed): seed in done for (_, cfg), done, rdir in zip(runs, finished, rdirs) for seed in cfg.seeds}
        console.print(f"{sum(jobs.values())} of {len(jobs)} seed jobs have records under {runs[0][1].runs_dir if runs else '-'}; {len(jobs) - sum(jobs.values())} to run")
        if args.check is not None:
            _report_config_changes(args.check, runs, rdirs, args.preset)
        return 0
    manifest = reproduce(
        args.preset, out, _registry(), err_console, args.executor, args.plan, overrides, args.only, args.ray_address, args.jobs or default_jobs(), args.first_seeds,
        budget_seconds=args.budget,
    )  # fmt: skip
    console.print(f"wrote {len(manifest['files'])} table files and manifest.json to {out} in {manifest['wall_seconds_total']:.1f} s")
    unfinished = manifest.get("unfinished") or {}
    if unfinished:
        done = len(manifest["tables"]) - len(unfinished)
        console.print(
            f"time budget of {args.budget:g} s: {done} of {len(manifest['tables'])} tables finished; not run (the same command resumes them): "
            + "; ".join(f"{t} ({len(rows)} row(s))" for t, rows in unfinished.items()),
            highlight=False,
        )
    if args.check is not None:
        if unfinished and len(unfinished) == len(manifest["tables"]):
            raise ClodsError(f"the time budget of {args.budget:g} s left no table to check", where="--budget", hint="give a larger budget")
        return _report_check(args.check, out, [t for t in manifest["tables"] if t not in unfinished], args.first_seeds, args.preset,
                             not_run=sorted(unfinished))  # fmt: skip
    return 0


def _report_check(committed: Path, fresh: Path, tables: Sequence[str], first_seeds: int | None, preset: str, not_run: Sequence[str] = ()) -> int:
    """`reproduce --check`: print what moved (rows with their first differing stage, table cells) and the tables to regenerate."""
    from clods_bench.benchmark.reproduction.regression_check import check_reproduction, regenerate_command

    if not_run:
        console.print(f"not checked (left by the time budget): {', '.join(not_run)}", highlight=False)
    report = check_reproduction(committed, fresh, tables, first_seeds)
    for note in report.notes:
        console.print(note, highlight=False)
    if report.ok:
        what = "first seed of every" if first_seeds is not None else "every"
        console.print(f"the {what} row of {len(tables)} table(s) in {fresh} equals {committed} (exact, or within its tolerance.yaml)", highlight=False)
        return 0
    if report.digest_lines:
        err_console.print(f"[bold red]{len(report.digest_lines)} row seed(s) moved[/bold red] (first stage that differs, metrics that moved):", highlight=False)
        for line in report.digest_lines:
            err_console.print(f"  {line}", highlight=False, markup=False)
    if report.table_lines:
        err_console.print(f"[bold red]{len(report.table_lines)} table cell(s) moved[/bold red] ({fresh} against {committed}):", highlight=False)
        for line in report.table_lines:
            err_console.print(f"  {line}", highlight=False, markup=False)
    err_console.print(f"tables to regenerate: {', '.join(report.tables)}; when the change is intended: {regenerate_command(preset, report.tables, str(committed))}",
                      highlight=False, markup=False)  # fmt: skip
    return 1


def _report_config_changes(committed: Path, runs: Sequence[tuple[Any, RunConfig]], rdirs: Sequence[Path], preset: str) -> None:
    """`reproduce --dry-run --check DIR`: the rows whose resolved config differs from the one DIR's digests were made
    with (their record keys differ), and the tables that must be regenerated for them."""
    from clods_bench.benchmark.reproduction import run_digests
    from clods_bench.benchmark.reproduction.regression_check import regenerate_command
    from clods_bench.benchmark.reproduction.reproduce import record_key, run_name

    committed_digests = run_digests.load(Path(committed) / run_digests.DIGESTS_FILE)
    current = {run_name(run): record_key(rdir) for (run, _), rdir in zip(runs, rdirs)}
    changed = run_digests.changed_configs(committed_digests, current)
    if not changed:
        console.print(f"every row's config is the one {committed} was made with (a code change can still move numbers: run the check)")
        return
    console.print(f"{len(changed)} row(s) with another config than {committed}'s:", highlight=False)
    for _, line in changed:
        console.print(f"  {line}", highlight=False, markup=False)
    names = [name for name, _ in changed]
    tables = list(dict.fromkeys([*run_digests.tables_of(names, committed_digests), *(run.table for run, _ in runs if run_name(run) in names)]))
    console.print(f"tables to regenerate: {', '.join(tables)}: {regenerate_command(preset, tables, str(committed))}", highlight=False, markup=False)


def _record_dirs(runs: Sequence[tuple[Any, RunConfig]], registry: Any) -> list[Path]:
    """Each run's record folder as `reproduce` resolves it: a row whose config differs from an earlier row's only in
    its label reads that row's record; plugin defaults filled, paths absolute."""
    from clods_bench.benchmark.running.seed_jobs import absolute_paths
    from clods_bench.benchmark.running.records import record_dir
    from clods_bench.benchmark.reproduction.reproduce import canonical_rows, run_name
    from clods_bench.benchmark.running.runner import resolve_plugin_configs

    canonical, same_as = canonical_rows(runs)
    dirs = {name: record_dir(resolve_plugin_configs(absolute_paths(copy.deepcopy(cfg)), registry)) for name, cfg in canonical}
    return [dirs[same_as[run_name(run)]] for run, _ in runs]


def _finished_seeds(runs: Sequence[tuple[Any, RunConfig]], rdirs: Sequence[Path]) -> list[list[int]]:
    """The seeds of each run whose results are recorded already in its record folder (what `reproduce` would skip)."""
    from clods_bench.benchmark.running.records import load_seed_result

    return [[int(s) for s in cfg.seeds if load_seed_result(rdir, int(s)) is not None] for (_, cfg), rdir in zip(runs, rdirs)]


def _report_comparison(committed: Path, fresh: Path, tolerance: Path | None, skip_columns: Sequence[str] = (), not_run: Sequence[str] = ()) -> int:
    """Compare and print; `not_run`: table ids a time budget left out, named as not checked (not a failure)."""
    from clods_bench.benchmark.reproduction.compare import compare_dirs

    if not_run:
        console.print(f"not checked (left by the time budget): {', '.join(not_run)}", highlight=False)
    problems = compare_dirs(committed, fresh, tolerance, skip_columns, skip_tables=not_run)
    if problems:
        err_console.print(f"[bold red]{len(problems)} number(s) moved beyond tolerance or tables differ[/bold red] ({fresh} vs committed {committed}):", highlight=False)
        for line in problems:
            err_console.print(f"  {line}", highlight=False, markup=False)
        return 1
    console.print(f"every compared number of {fresh} is within tolerance of {committed}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    return _report_comparison(args.committed, args.fresh, args.tolerance)


def cmd_seed_spread(args: argparse.Namespace) -> int:
    from clods_bench.atomic import write_text
    from clods_bench.benchmark.reproduction.compare import seed_spread

    frame = seed_spread(args.runs, args.task)
    if frame.empty:
        raise ClodsError("no record with at least 2 seeds and finite metrics", where=str(args.runs))
    summary = frame.groupby(["task", "label", "preset"]).agg(metrics=("metric", "size"), seeds=("seeds", "max"), median_rel_std=("rel_std", "median"),
                                                              max_rel_std=("rel_std", "max"), max_rel_dev=("max_rel_dev", "max")).reset_index()  # fmt: skip
    table = Table(title=f"seed-to-seed variation of the metrics ({args.runs}); rel = / |mean over seeds|")
    for col in summary.columns:
        table.add_column(str(col), justify="right")
    for row in summary.itertuples(index=False):
        table.add_row(*[f"{v:.3g}" if isinstance(v, float) else str(v) for v in row])
    console.print(table)
    if args.csv is not None:
        write_text(args.csv, frame.to_csv(index=False))
        console.print(f"wrote {args.csv}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    views = 8 if args.views is None else args.views
    frames = 12 if args.frames is None else args.frames
    fit_iterations = 60 if args.fit_iterations is None else args.fit_iterations
    if args.what == "data":
        from clods_bench.benchmark.speed.bench import bench_data

        bench_data(console, steps=args.steps, views=views)
    elif args.what == "infer":
        from clods_bench.benchmark.core.config import load_config
        from clods_bench.benchmark.speed.infer_bench import check_device
        from clods_bench.benchmark.outputs.infer_output import print_bench_infer

        check_device(args.device)  # before any work: one line when CUDA is absent
        cfg = load_config(args.preset, None, list(args.overrides))
        print_bench_infer(console, cfg, args.out, progress=not args.no_progress, sim=args.sim, frames=5 if args.frames is None else args.frames,
                          views=args.views, device=args.device, fit_iterations=args.fit_iterations or 0)  # fmt: skip
    elif args.what == "video":
        from clods_bench.benchmark.core.config import load_config
        from clods_bench.benchmark.speed.infer_bench import check_device
        from clods_bench.benchmark.speed.video_bench import bench_video

        check_device(args.device, where="bench video --device")
        bench_video(console, load_config(args.preset, None, list(args.overrides)), predictors=args.predictors, devices=("cpu", args.device),
                    cpu=args.cpu or args.device == "cpu")
    elif args.what == "store":
        from clods_bench.benchmark.core.config import load_config
        from clods_bench.datasets.store_bench import print_bench_store

        cfg = load_config(args.preset, None, list(args.overrides))
        print_bench_store(console, cfg, _registry().get("scene", cfg.data.scene), blocks=args.blocks)
    elif args.what == "render":
        from clods_bench.splatting.bench import print_bench_render

        print_bench_render(console, repeats=args.repeats, size=args.size, num_cameras=views, gsplat=args.gsplat,
                           reference=args.reference)  # fmt: skip
    elif args.what == "determinism":
        from clods_bench.benchmark.speed.determinism_bench import bench_determinism

        bench_determinism(console, repeats=args.repeats)
    elif args.what == "stage2":
        from clods_bench.benchmark.speed.stage2_bench import print_bench_stage2

        print_bench_stage2(console, preset=args.preset, frames=frames, fit_iterations=fit_iterations,
                           backends=("cpu", "reference") if args.reference else ("cpu",))  # fmt: skip
    else:
        from clods_bench.benchmark.core.config import parse_override
        from clods_bench.benchmark.speed.infer_bench import check_device
        from clods_bench.benchmark.speed.sim_bench import bench_sim, sim_overrides

        check_device(args.device, where="bench sim --device")
        sim_config = sim_overrides([parse_override(o) for o in args.overrides])
        bench_sim(console, sims=args.sims, frames=frames, sim_config=sim_config, devices=("cpu", args.device))
    return 0


SCOPED_COMMANDS = ("data", "run", "reproduce", "bench", "numerics")
"""Commands that compute with the numeric libraries: they run inside the exact scope unless --no-deterministic."""


def _exact_scope(args: argparse.Namespace) -> Any:
    """The exact scope for a computing command (None for the others, and with --no-deterministic or
    CLODS_BENCH_DETERMINISTIC=0)."""
    from clods_bench import numerics

    if args.command not in SCOPED_COMMANDS or args.no_deterministic or not numerics.requested():
        return None
    if args.command == "numerics" and (args.export or numerics.missing_cpu_features()):
        return None  # `numerics` still reports on a CPU the scope cannot pin
    return numerics.exact()


@contextlib.contextmanager
def _switch_for_workers(off: bool) -> Iterator[None]:
    """With --no-deterministic, $CLODS_BENCH_DETERMINISTIC=0 for the command's duration: its worker processes and
    runner then stay on the host's paths too."""
    import os

    from clods_bench.numerics import SWITCH_ENV

    before = os.environ.get(SWITCH_ENV)
    if off:
        os.environ[SWITCH_ENV] = "0"
    try:
        yield
    finally:
        if off:
            if before is None:
                os.environ.pop(SWITCH_ENV, None)
            else:
                os.environ[SWITCH_ENV] = before


def main(argv: Sequence[str] | None = None) -> int:
    from clods_bench import numerics

    argv = list(sys.argv[1:] if argv is None else argv)
    if "--no-deterministic" not in argv and numerics.requested():
        numerics.pin_environment()  # first: building the parser loads the plugins, and they load numpy
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from clods_bench.benchmark.core.plugin_report import plugin_options

        with _switch_for_workers(args.no_deterministic), contextlib.ExitStack() as stack:
            scope = _exact_scope(args)
            if scope is not None:
                stack.enter_context(scope)
            stack.enter_context(plugin_options(args.strict_plugins, err_console))
            return int(args.func(args) or 0)
    except ClodsError as exc:
        if args.debug:
            raise
        err_console.print(f"[bold red]error:[/bold red] {exc.message}", highlight=False)
        return 2
    except KeyboardInterrupt:
        err_console.print("interrupted; finished work is kept and the next run resumes")
        return 130
    except Exception as exc:  # an internal error: short message unless --debug
        if args.debug:
            raise
        err_console.print(f"[bold red]internal error:[/bold red] {type(exc).__name__}: {exc} (rerun with --debug for the traceback)", highlight=False)
        return 1


if __name__ == "__main__":
    sys.exit(main())
