"""The blocks of TAU's translator (Tan et al. CVPR 2023, "Temporal Attention Unit"), as in the authors' code (OpenSTL's
`TAUSubBlock` inside a `MetaBlock`): a MetaFormer block x + s1 * attention(BN(x)), x + s2 * MLP(BN(x)) with layer
scales (init 0.01) and stochastic depth, then a 1x1 convolution where the block changes the width.

The attention is TAU's: statical (a depthwise conv, a dilated depthwise conv and a 1x1 conv: a large receptive
field) times dynamical (squeeze-and-excitation gates from the channels' spatial means) times its input, between two
1x1 convs and a GELU, plus a shortcut. The MLP is VAN's: 1x1 conv, 3x3 depthwise conv, GELU, 1x1 conv. Initialisation
as OpenSTL leaves it: the MLP from a normal of std sqrt(2 / fan_out), attention, gates and width change at
PyTorch's defaults (OpenSTL builds TAU's attention after its block's initialiser ran), BatchNorm at 1 and 0.
"""

from __future__ import annotations

import torch
from torch import nn

from clods_bench.plugins.video.weight_init import fan_out_normal_init


def lka_kernels(kernel_size: int, dilation: int) -> tuple[int, int]:
    """(depthwise kernel, dilated depthwise kernel) decomposing a kernel_size x kernel_size attention (VAN / TAU rule)."""
    k = kernel_size // dilation
    return 2 * dilation - 1, k + (k % 2 - 1)


class TemporalAttentionModule(nn.Module):
    """static(x) * dynamical(x) * x on (B,C,h,w): large-kernel spatial attention times channel (SE) attention."""

    def __init__(self, dim: int, kernel_size: int = 21, dilation: int = 3, reduction: int = 16) -> None:
        super().__init__()
        d_k, dd_k = lka_kernels(kernel_size, dilation)
        self.conv0 = nn.Conv2d(dim, dim, d_k, padding=d_k // 2, groups=dim)
        self.conv_spatial = nn.Conv2d(dim, dim, dd_k, padding=dilation * (dd_k // 2), groups=dim, dilation=dilation)
        self.conv1 = nn.Conv2d(dim, dim, 1)
        hidden = dim // max(dim // reduction, 4)  # OpenSTL's squeeze width
        self.fc = nn.Sequential(nn.Linear(dim, hidden, bias=False), nn.ReLU(), nn.Linear(hidden, dim, bias=False), nn.Sigmoid())

    def static(self, x: torch.Tensor) -> torch.Tensor:
        """Intra-frame statical attention (B,C,h,w): depthwise conv, dilated depthwise conv, 1x1 conv."""
        return self.conv1(self.conv_spatial(self.conv0(x)))

    def dynamical(self, x: torch.Tensor) -> torch.Tensor:
        """Inter-frame dynamical attention (B,C,1,1): sigmoid gates from the channels' spatial means."""
        return self.fc(x.mean(dim=(2, 3))).unsqueeze(-1).unsqueeze(-1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.dynamical(x) * self.static(x) * x


class TemporalAttention(nn.Module):
    """1x1 conv, GELU, the attention module, 1x1 conv, plus the input (OpenSTL's `TemporalAttention`)."""

    def __init__(self, dim: int, kernel_size: int) -> None:
        super().__init__()
        self.proj_1 = nn.Conv2d(dim, dim, 1)
        self.act = nn.GELU()
        self.unit = TemporalAttentionModule(dim, kernel_size)
        self.proj_2 = nn.Conv2d(dim, dim, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj_2(self.unit(self.act(self.proj_1(x)))) + x


class MixMlp(nn.Module):
    """1x1 conv to `hidden`, 3x3 depthwise conv, GELU, 1x1 conv back; VAN's initialisation."""

    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.fc1 = nn.Conv2d(dim, hidden, 1)
        self.dwconv = nn.Conv2d(hidden, hidden, 3, padding=1, groups=hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Conv2d(hidden, dim, 1)
        fan_out_normal_init(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.dwconv(self.fc1(x))))


class DropPath(nn.Module):
    """Stochastic depth: in training, zero a sample's branch with probability p and scale the kept ones by 1/(1-p)."""

    def __init__(self, p: float) -> None:
        super().__init__()
        self.p = p

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p <= 0.0:
            return x
        keep = 1.0 - self.p
        mask = x.new_empty((x.shape[0],) + (1,) * (x.ndim - 1)).bernoulli_(keep)
        return x * mask.div_(keep)


class TauBlock(nn.Module):
    """MetaFormer block with TAU attention, layer scales (init 0.01) and stochastic depth `drop_path`; then a 1x1 conv
    when c_in != c_out."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, mlp_ratio: float, drop_path: float = 0.0) -> None:
        super().__init__()
        self.norm1 = nn.BatchNorm2d(c_in)
        self.attn = TemporalAttention(c_in, kernel_size)
        self.norm2 = nn.BatchNorm2d(c_in)
        self.mlp = MixMlp(c_in, int(c_in * mlp_ratio))
        self.drop_path = DropPath(drop_path)
        self.layer_scale_1 = nn.Parameter(torch.full((c_in,), 1e-2))
        self.layer_scale_2 = nn.Parameter(torch.full((c_in,), 1e-2))
        self.reduction: nn.Module = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.drop_path(self.layer_scale_1[:, None, None] * self.attn(self.norm1(x)))
        x = x + self.drop_path(self.layer_scale_2[:, None, None] * self.mlp(self.norm2(x)))
        return self.reduction(x)


def drop_path_rates(num_layers: int, drop_path: float) -> list[float]:
    """Stochastic-depth rate of each translator block, OpenSTL's rule: linspace(0.01, drop_path) for all but the last
    block, `drop_path` for the last (so drop_path 0 still drops the early blocks' branches with 1 % down to ~0 %)."""
    rates = torch.linspace(1e-2, drop_path, num_layers).tolist()
    return rates[:-1] + [drop_path]
