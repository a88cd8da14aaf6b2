"""`clods-bench bench WHAT`: the speed benchmarks, each a ratio against a reference measured in the same run."""

from __future__ import annotations

import argparse
from pathlib import Path

from clods_bench.cli.common import console, plugin_registry


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this group's commands to the `clods-bench` parser."""
    p = sub.add_parser("bench", help="speed benchmarks (ratios against a reference measured in the same run)")
    p.add_argument("what", choices=("data", "render", "sim", "stage2", "store", "infer", "video", "determinism", "threads"),
                   help="data: cloth solver and ground-truth rasterizer; render: fast CPU splatting vs the torch reference; "
                        "sim: train/inference step time of each simulator vs the physics solver; "
                        "stage2: CloDS stage-2 ms per iteration and per frame at --preset scale, cpu vs the torch reference; "
                        "store: frame store bytes and read speed vs raw .npy; "
                        "infer: ms per frame of CloDS (learned step + SMGS render of every view) vs the traditional pipeline "
                        "(physics solver step + ground-truth rasterizer) at --preset size; "
                        "video: training-step time of each video predictor at --preset size and its preset training time; "
                        "determinism: deterministic mode's cost, MGN and CPU splatting against the host's own paths; "
                        "threads: MGN's small training step on --threads counts against the first, and whether each model "
                        "family keeps its bits")  # fmt: skip
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
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="threads: thread counts per job, the first the reference (default 1 2)")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args: argparse.Namespace) -> int:
    views = 8 if args.views is None else args.views
    frames = 12 if args.frames is None else args.frames
    fit_iterations = 60 if args.fit_iterations is None else args.fit_iterations
    if args.what == "threads":
        from clods_bench.benchmark.speed.thread_bench import bench_threads

        bench_threads(console, counts=args.threads, frames=8 if args.frames is None else args.frames)
    elif args.what == "data":
        from clods_bench.benchmark.speed.bench import bench_data

        bench_data(console, steps=args.steps, views=views)
    elif args.what == "infer":
        from clods_bench.benchmark.core.config import load_config
        from clods_bench.benchmark.speed.infer_bench import check_device
        from clods_bench.benchmark.speed.infer_console import print_bench_infer

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
        print_bench_store(console, cfg, plugin_registry().get("scene", cfg.data.scene), blocks=args.blocks)
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
