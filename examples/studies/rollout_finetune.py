"""Does fine-tuning on the K-step rollout loss keep a learned simulator's long rollouts in one piece?

Issue 14, item 4: at `small`, MGN and BSMS trained on the one-step loss tear the flag over the stability task's 2x
horizon (largest edge strain 0.91 / 1.74, every rollout crossing 0.5 strain). This takes the finished fit of a
`run stability --sim <sim> --preset <preset>` row from the fit cache (it never trains that fit: without it the study
stops), copies its model, trains it further on the same training meshes with CloDS's rollout loss (eq. 8: K steps
unrolled and backpropagated; `sim_config.<sim>.loss=rollout`), and scores the same long rollouts as the stability
task (4 unviewed trajectories, 2x horizon, re-simulated ground truth) before fine-tuning and every `every` steps.

    python examples/studies/rollout_finetune.py bsms small --steps 1000 --every 250 --k 8 [--threads 1]

Prints one line per scored model: fine-tuning step, RMSE over the horizon, largest edge strain, rollouts past 0.5
strain, first failure frame. The fine-tuned fits live in `<runs_dir>/studies/rollout_finetune/fit_cache` (resumable),
apart from the fit cache of the benchmark's rows.
"""

from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path

import torch

from clods_bench.benchmark.core.builders import build_simulator, fit_on_meshes, split_spec
from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.fit_cache import fit_work_dir, sim_fit_identity
from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.tasks.stability import horizon_frames, long_rollouts, rollout_summary, stability_config
from clods_bench.datasets.store import DatasetStore


def score(ctx, sim, store, name: str) -> dict:
    """The stability task's summary of `sim`'s long rollouts on the unviewed trajectories."""
    splits, scfg = split_spec(ctx), stability_config(ctx)
    frames = horizon_frames(splits.num_steps, scfg.horizon_factor)
    rows, _, _ = long_rollouts(ctx, sim, ctx.registry.get("scene", ctx.config.data.scene), store, splits, list(splits.unviewed),
                                frames, scfg, name, progress=False)  # fmt: skip
    out = rollout_summary(list(rows.values()), frames)
    out["first_failure"] = min((r["failure_frame"] for r in rows.values() if r["failure_frame"] is not None), default=None)
    return out


def line(step: int, s: dict, seconds: float) -> str:
    return (f"step {step:6d}: RMSE {s['rmse']:.4f} m, max strain {s['max_strain']:.3f}, past 0.5: "
            f"{s['diverged_fraction'] * 4:.0f}/4, first failure frame {s['first_failure']}, {seconds:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sim")
    ap.add_argument("preset")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--every", type=int, default=250)
    ap.add_argument("--k", type=int, default=8)
    ap.add_argument("--lr", type=float, default=None, help="learning_rate of the fine-tuning (default: the config's)")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    reg = default_registry()
    cfg = load_config(args.preset, None, [f"sim={args.sim}", "task=stability", "seeds=[0]"])
    ctx = TaskContext(config=cfg, seed=0, work_dir=Path(cfg.runs_dir), registry=reg)
    store = DatasetStore.open(cfg.data.dataset_dir())
    splits = split_spec(ctx)
    train_ids = list(splits.train)
    base = build_simulator(ctx)
    work = fit_work_dir(ctx, sim_fit_identity(ctx, train_ids, splits.interp_steps + 1, supervision="mesh"))
    ckpt = work / base.checkpoint_name
    if not ckpt.exists() or torch.load(ckpt, map_location="cpu", weights_only=False)["trainer"]["step"] < base.config.train_steps:
        raise SystemExit(f"no finished fit in {work}: run `clods-bench run stability --sim {args.sim} --preset {args.preset} "
                         f"--set seeds=[0]` first (this study does not train it)")
    fit_on_meshes(ctx, base, store)  # loads the finished checkpoint
    t0 = time.perf_counter()
    print(line(0, score(ctx, base, store, args.sim), time.perf_counter() - t0), flush=True)

    over = {"loss": "rollout", "rollout_length": args.k, "rollout_start_step": 0, "train_steps": args.steps, "warmup_steps": 0,
            "checkpoint_every": args.every}
    if args.lr is not None:
        over["learning_rate"] = f"{args.lr:.6e}"  # with a '.', so YAML reads a float
    if args.threads is not None:
        over["num_threads"] = args.threads
    out = Path(cfg.runs_dir) / "studies" / "rollout_finetune"
    tuned_cfg = load_config(args.preset, None, [f"sim={args.sim}", "task=stability", "seeds=[0]", f"runs_dir={out}"]
                            + [f"sim_config.{args.sim}.{k}={v}" for k, v in over.items()])  # fmt: skip
    tctx = TaskContext(config=tuned_cfg, seed=0, work_dir=out, registry=reg)
    tuned = build_simulator(tctx)
    trained = copy.deepcopy(base.model)
    tuned.build_model = lambda seed: copy.deepcopy(trained).train()
    t1 = time.perf_counter()
    fit_on_meshes(tctx, tuned, store, snapshot_every=args.every, identity_extra={"finetuned_from": work.name})
    fit_seconds = time.perf_counter() - t1
    for step, path in tuned.snapshots(fit_work_dir(tctx, sim_fit_identity(tctx, train_ids, splits.interp_steps + 1, supervision="mesh",
                                                                             finetuned_from=work.name))):  # fmt: skip
        tuned.use_snapshot(path)
        t2 = time.perf_counter()
        print(line(step, score(tctx, tuned, store, args.sim), time.perf_counter() - t2), flush=True)
    print(f"fine-tuning: {args.steps} steps of the {args.k}-step rollout loss in {fit_seconds:.0f} s", flush=True)


if __name__ == "__main__":
    main()
