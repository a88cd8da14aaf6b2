"""The `device` option of trainable plugins (learned simulators, video predictors): its check and its torch device.

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
