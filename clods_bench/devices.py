"""The `device` option of trainable plugins (learned simulators, video predictors): its check and its torch device;
and the run's device (`--device`: 'auto' decided, a GPU that is not there named in one line).

One rule for every config that has the option: 'cpu', 'cuda' or 'cuda:N'; asking for CUDA where torch sees none is
one ClodsError naming the field, raised before anything is trained or written.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    import torch

DEVICE_PATTERN = re.compile(r"cpu|cuda(:\d+)?")


def check_device_name(value: Any, where: str) -> None:
    """Raise ClodsError at `where` unless `value` is 'cpu', 'cuda' or 'cuda:N'."""
    if not isinstance(value, str) or not DEVICE_PATTERN.fullmatch(value):
        raise ClodsError(f"must be 'cpu', 'cuda' or 'cuda:N', got {value!r}", where=where)


def torch_device(value: str, where: str) -> "torch.device":
    """The torch device `value` names, checked to exist (ClodsError at `where` when CUDA is asked for but absent)."""
    import torch

    check_device_name(value, where)
    if value != "cpu" and not torch.cuda.is_available():
        raise ClodsError(f"device '{value}' asked for, but torch sees no CUDA GPU", where=where,
                         hint="install a CUDA build of torch on a GPU machine, or use device: cpu")  # fmt: skip
    return torch.device(value)


RUN_DEVICES = "auto, cpu, cuda or cuda:N"
"""The values of a run's `device` (`--device`): 'auto' takes a GPU when torch sees one."""


def device_kind(value: str) -> str:
    """'cpu' or 'cuda': the kind of device `value` ('cpu', 'cuda', 'cuda:N') names."""
    return str(value).split(":", 1)[0]


def check_run_device(value: Any, where: str) -> str:
    """`value` unless it is not a run device ('auto', 'cpu', 'cuda', 'cuda:N'): then a ClodsError at `where`."""
    if value != "auto":
        if not isinstance(value, str) or not DEVICE_PATTERN.fullmatch(value):
            raise ClodsError(f"must be {RUN_DEVICES}, got {value!r}", where=where)
    return str(value)


def resolve_device(value: str, where: str, check: bool = True) -> str:
    """The device a run's `value` names here: 'auto' becomes 'cuda' when torch sees a CUDA GPU, else 'cpu'.

    With `check`, 'cuda' without a GPU and 'cuda:N' past the last GPU are one ClodsError at `where` (e.g.
    '--device cuda'); without it (a Ray driver whose workers hold the GPUs) only the name is checked."""
    value = check_run_device(value, where)
    if value == "cpu":
        return value
    import torch

    if value == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if not check:
        return value
    if not torch.cuda.is_available():
        why = "is a CPU build" if torch.version.cuda is None else f"(CUDA {torch.version.cuda}) sees no GPU"
        raise ClodsError(f"no CUDA device is available (torch {torch.__version__} {why})", where=f"{where} {value}")
    index, count = int(value[5:] or 0), torch.cuda.device_count()
    if index >= count:
        names = " and ".join(f"cuda:{i}" for i in range(count)) if count <= 2 else f"cuda:0 to cuda:{count - 1}"
        raise ClodsError(f"only {names} {'exists' if count == 1 else 'exist'}", where=f"{where} {value}")
    return value
