"""Helpers shared by the same-weights studies: the reference checkout check, meshes, differences, the result file."""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from clods_bench.datasets.meshes import make_flag_mesh, make_flagsimple_mesh
from clods_bench.plugins.simulators.learned.graph import mesh_edges


def fail(message: str) -> None:
    """Print one line and exit with status 1."""
    print(message)
    raise SystemExit(1)


def reference_args(doc: str, reference: str, commit: str) -> argparse.Namespace:
    """The study's command line: the reference checkout (which must exist) and `--out`."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("reference", type=Path, help=f"git checkout of {reference} at {commit}")
    parser.add_argument("--out", type=Path, help="also write the lines to this file")
    args = parser.parse_args()
    if not args.reference.is_dir():
        fail(f"{args.reference}: no such directory (a checkout of {reference} at {commit})")
    return args


def emit(lines: list[str], out: Path | None) -> None:
    """Print a study's lines, and write them to `out` as well when given (its folder made)."""
    print("\n".join(lines))
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("\n".join(lines) + "\n")


def check_checkout(path: Path, marker: str, reference: str, commit: str) -> None:
    """One clear line and exit unless `path` is a git checkout of `reference` at `commit` holding `marker`."""
    if not (path / marker).is_file():
        fail(f"{path}: no {marker} here; expected a checkout of {reference}")
    head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        fail(f"{path}: not a git checkout ({head.stderr.strip()}); expected {reference} at {commit}")
    if head.stdout.strip() != commit:
        fail(f"{path}: checkout is at {head.stdout.strip()}, this study knows {reference} at {commit}")


def study_meshes() -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(name, senders, receivers, mesh_pos (V,2), world_pos (V,3)) float64 graphs: the ci and small flags, the
    FLAGSIMPLE-size flag, a jittered flag and a batch of two flags (two components)."""
    out = []
    rng = np.random.default_rng(0)

    def add(name: str, cells: np.ndarray, mesh_pos: np.ndarray) -> None:
        s, r = mesh_edges(cells)
        mp = np.asarray(mesh_pos, dtype=np.float64)
        world = np.stack([mp[:, 0], 0.05 * np.sin(6.0 * mp[:, 0]) + 0.01 * rng.standard_normal(len(mp)), mp[:, 1]], 1)
        out.append((name, s, r, mp, world))

    for name, (nx, ny) in (("flag 16x8 (ci)", (16, 8)), ("flag 24x12 (small)", (24, 12))):
        m = make_flag_mesh(nx, ny)
        add(name, m.cells, m.mesh_pos)
    m = make_flagsimple_mesh()
    add("flag 1579 nodes (FLAGSIMPLE size)", m.cells, m.mesh_pos)
    m = make_flag_mesh(11, 7)
    add("flag 11x7, rest positions jittered", m.cells, m.mesh_pos + rng.uniform(-0.02, 0.02, m.mesh_pos.shape))
    a, b = make_flag_mesh(9, 5), make_flag_mesh(7, 6)
    add("two flags 9x5 + 7x6 (a batch)", np.concatenate([a.cells, b.cells + a.num_nodes]), np.concatenate([a.mesh_pos, b.mesh_pos + 3.0]))
    return out


def max_differences(ours: torch.Tensor, ref: torch.Tensor) -> tuple[float, float]:
    """(max |ours - ref|, that over max |ref|)."""
    d = float((ours.detach() - ref.detach()).abs().max()) if ours.numel() else 0.0
    scale = float(ref.detach().abs().max()) if ref.numel() else 0.0
    return d, d / scale if scale > 0 else d


def cpu_name() -> str:
    """The CPU's model name (lscpu), for the result file."""
    try:
        for line in subprocess.run(["lscpu"], capture_output=True, text=True).stdout.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def write_result(path: Path, reference: str, commit: str, command: str, body: dict[str, Any]) -> None:
    """The result file: the reference and commit, the command, the host, the date, then the study's numbers."""
    path.parent.mkdir(parents=True, exist_ok=True)
    head = {
        "reference": reference,
        "commit": commit,
        "command": command,
        "date": datetime.date.today().isoformat(),
        "cpu": cpu_name(),
        "python": sys.version.split()[0],
        "torch": torch.__version__,
    }
    path.write_text(json.dumps({**head, **body}, indent=1) + "\n")
    print(f"wrote {path}")
