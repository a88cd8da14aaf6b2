"""Which torch operation makes two CPUs' bits part: trace one tiny fit, on each CPU, then compare the two traces.

`trace FIT OUT` runs one of the determinism probe's fits (graph net, video predictor, renderer fit, extraction) or
a tiny fit of TAU, MAU or MMVP (`tau-ci`, `mau-ci`, `mmvp-ci`: three steps at the `ci` preset's widths) under a
dispatch mode that records, for every torch operation, a hash of its float
inputs and of its outputs. `compare A B` lists the operations that were given the same inputs in both traces and
returned other outputs: the kernels that depend on the CPU. Run the trace natively and under an emulated CPU, e.g.

    python examples/studies/op_trace.py trace "graph net" /tmp/xeon.json
    qemu-x86_64 -cpu EPYC-Rome .venv/bin/python examples/studies/op_trace.py trace "graph net" /tmp/rome.json
    python examples/studies/op_trace.py compare /tmp/xeon.json /tmp/rome.json

Intel Xeon Sapphire Rapids against QEMU 7.2's EPYC-Rome, 2026-11-29: without `clods_bench.numerics.exact_math`, `aten.sqrt`
(and Adam's `_foreach_sqrt`) were the only such operations in all four probe fits (graph net: sqrt x20,
_foreach_sqrt x1); with it, none are, in those four and in the TAU, MAU and MMVP fits.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

import clods_bench  # noqa: F401  (the pins, before numpy and torch)
from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.benchmark.speed import determinism_probe as probe

VIDEO = {"tau": {"hid_s": 8, "hid_t": 16, "enc_layers": 2, "trans_layers": 2, "kernel_size": 7, "mlp_ratio": 2.0},
         "mau": {"hidden": 8, "num_layers": 2, "tau": 2, "downsamples": 1},
         "mmvp": {"channels": 8, "predictor_channels": 4}}  # fmt: skip


_UNCOMPARABLE = ("empty", "uniform", "normal", "bernoulli", "rand", "exponential", "multinomial", "random")
"""Operations whose outputs are not functions of their tensor inputs: uninitialised memory, the random generators."""


def _hash(t: torch.Tensor) -> str:
    return hashlib.sha1(t.detach().contiguous().numpy().tobytes()).hexdigest()[:12]


class _Recorder(TorchDispatchMode):
    """Appends (operation, input hashes, output hashes) for every operation with a float output."""

    def __init__(self) -> None:
        super().__init__()
        self.log: list[tuple[str, list[str], list[str]]] = []

    def __torch_dispatch__(self, func: Any, types: Any, args: Any = (), kwargs: Any = None) -> Any:
        ins = [_hash(a) if isinstance(a, torch.Tensor) and a.device.type == "cpu" and not a.is_sparse else repr(a)[:40]
               for a in tree_flatten((args, kwargs))[0]]  # fmt: skip
        out = func(*args, **(kwargs or {}))
        if not any(k in str(func) for k in _UNCOMPARABLE):
            outs = [_hash(t) for t in tree_flatten(out)[0] if isinstance(t, torch.Tensor) and t.dtype.is_floating_point]
            if outs:
                self.log.append((str(func), ins, outs))
        return out


def _ci_values(name: str) -> dict[str, Any]:
    """The `ci` preset's settings of video predictor `name` (threads left to deterministic mode)."""
    import yaml

    preset = Path(clods_bench.__file__).parent / "benchmark" / "presets" / "ci.yaml"
    values = dict(yaml.safe_load(preset.read_text())["video_config"][name])
    values.pop("num_threads", None)
    return values


def trace(fit: str, out: Path) -> None:
    """Run `fit` under the recorder; write {'digest', 'log'} to `out`."""
    recorder = _Recorder()
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        if fit.removesuffix("-ci") in VIDEO:
            name = fit.removesuffix("-ci")
            if fit.endswith("-ci"):  # the `ci` preset's widths, 64 px, three steps
                values, size, frames = {**_ci_values(name), "train_steps": 3}, 64, 12
            else:
                values, size, frames = {**VIDEO[name], "context_frames": 3, "train_steps": 4, "batch_size": 2}, 32, 8
            pred = probe._build("video_predictor", name, {**values, "checkpoint_every": 1000}, work)
            videos = [np.stack([probe._images(1, size, 0.3 * k + v)[0] for k in range(frames)]) for v in range(3)]
            with recorder:
                pred.fit(videos, FitContext(work_dir=work / fit, seed=0, progress=False))
            digest = probe._digest(pred)
        elif fit in probe.PROBES:
            with recorder:
                digest = probe.PROBES[fit](work)
        else:
            raise SystemExit(f"unknown fit {fit!r}: one of {', '.join([*probe.PROBES, *VIDEO, *(v + '-ci' for v in VIDEO)])}")
    out.write_text(json.dumps({"fit": fit, "digest": digest, "log": recorder.log}))
    print(f"{fit}: digest {digest}, {len(recorder.log)} operations -> {out}")


def compare(a: Path, b: Path) -> None:
    """Print the operations given the same inputs in both traces that returned other outputs."""
    ta, tb = json.loads(a.read_text()), json.loads(b.read_text())
    seen: dict[tuple[str, tuple[str, ...]], list[list[str]]] = collections.defaultdict(list)
    for f, i, o in ta["log"]:
        seen[(f, tuple(i))].append(o)
    moved = collections.Counter(f for f, i, o in tb["log"] if (f, tuple(i)) in seen and o not in seen[(f, tuple(i))]
                                 and not any(k in f for k in _UNCOMPARABLE))
    print(f"digests {ta['digest']} / {tb['digest']}; operations {len(ta['log'])} / {len(tb['log'])}")
    print("same inputs, other outputs: " + (", ".join(f"{f} x{n}" for f, n in moved.most_common()) or "none"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("trace")
    p.add_argument("fit")
    p.add_argument("out", type=Path)
    p = sub.add_parser("compare")
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    args = parser.parse_args()
    trace(args.fit, args.out) if args.cmd == "trace" else compare(args.a, args.b)


if __name__ == "__main__":
    main()
