"""Where a renderer fits: `device` 'cpu' or 'cuda' ('cuda:N'). On a GPU the parameters, the target images and the
loss live there and only backend 'gsplat' renders, so a fit iteration moves no image between host and GPU;
`render` still returns images on the device of the vertices it is given (callers need not know).
"""

from __future__ import annotations

import torch
from torch import Tensor

from clods_bench.errors import ClodsError


def check_device_config(device: str, backend: str, where: str) -> None:
    """Raise ClodsError unless `device` is 'cpu' or 'cuda[:N]', and a GPU device goes with backend 'gsplat'."""
    name = str(device)
    if not (name == "cpu" or name == "cuda" or (name.startswith("cuda:") and name[5:].isdigit())):
        raise ClodsError(f"unknown device '{name}'; known: cpu, cuda, cuda:N", where=f"{where}.device")
    if name != "cpu" and backend != "gsplat":
        raise ClodsError(f"device '{name}' needs backend 'gsplat'; backend '{backend}' runs on the CPU", where=f"{where}.device",
                         hint=f"set {where}.backend=gsplat, or device=cpu")  # fmt: skip


def fit_device(device: str, where: str) -> torch.device:
    """The torch device to fit on; a clear error when CUDA is asked for and absent."""
    if str(device) != "cpu" and not torch.cuda.is_available():
        raise ClodsError(f"device '{device}' asked for, but torch sees no CUDA GPU", where=f"{where}.device",
                         hint="set device=cpu (and backend=cpu) on a machine without a GPU")  # fmt: skip
    return torch.device(device)


def leaf_to(t: Tensor, device: torch.device) -> Tensor:
    """A copy of a parameter on `device` that is again a leaf and keeps requires_grad."""
    return t.detach().to(device).requires_grad_(t.requires_grad)


def tensors_to(obj: object, device: torch.device) -> object:
    """`obj` with every tensor in it (nested in tuples, lists and dicts) moved to `device`."""
    if isinstance(obj, Tensor):
        return obj.to(device)
    if isinstance(obj, tuple):
        return tuple(tensors_to(x, device) for x in obj)
    if isinstance(obj, list):
        return [tensors_to(x, device) for x in obj]
    if isinstance(obj, dict):
        return {k: tensors_to(v, device) for k, v in obj.items()}
    return obj
