"""`clods-bench data ...`: generate, convert, digest, import and export datasets, and export a run's meshes."""

from __future__ import annotations

import argparse
from pathlib import Path

from clods_bench.cli.common import add_config_args, console, err_console, plugin_registry, run_config
from clods_bench.errors import ClodsError


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this group's commands to the `clods-bench` parser."""
    data = sub.add_parser("data", help="generate, import and export datasets")
    dsub = data.add_subparsers(dest="data_command", required=True)
    p = dsub.add_parser("generate", help="simulate and render a scene's dataset (resumable)")
    add_config_args(p)
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
    p.add_argument("--split", default="train", help="which split's TFRecord in SOURCE to convert (default train)")
    p.add_argument("--limit", type=int, default=None, help="number of trajectories to convert")
    p.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    p.set_defaults(func=cmd_data_import)
    p = dsub.add_parser("export", help="write a stored trajectory as an OBJ/PLY sequence, or the dataset in the NeRF layout")
    add_config_args(p)
    p.add_argument("--traj", type=int, nargs="+", default=None,
                   help="trajectories (default: 0 for obj/ply, every one for nerf)")  # fmt: skip
    p.add_argument("--format", choices=("obj", "ply", "nerf"), default="obj",
                   help="obj/ply: one mesh file per frame; nerf: per trajectory a transforms.json (camera-to-world, OpenGL "
                        "axes) and a PNG folder per camera")  # fmt: skip
    p.add_argument("--meshes", choices=("obj", "ply", "none"), default="none", help="nerf: also write the meshes per frame")
    p.add_argument("--out", type=Path, required=True, help="folder to write the files into (created if missing)")
    p.set_defaults(func=cmd_data_export)
    p = dsub.add_parser("export-meshes", help="write the meshes a run saved (seed_N/*.npz: initial, extracted, rollout) as OBJ/PLY sequences")
    p.add_argument("sample", type=Path, help="a run's mesh sample, e.g. runs/cdg/<label>/<id>/seed_0/extraction_meshes.npz")
    p.add_argument("--format", choices=("obj", "ply"), default="obj", help="mesh file format, one file per frame (default obj)")
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


def cmd_data_generate(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.running.executors import make_executor
    from clods_bench.datasets.generate import generate

    cfg = run_config(args)
    scene = plugin_registry().get("scene", cfg.data.scene)
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

    cfg = run_config(args)
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
