"""The TAU network (Tan et al. CVPR 2023, "Temporal Attention Unit"): SimVP v2 with a translator of TAU blocks,
and TAU's differential divergence regularisation.

Encoder and decoder are SimVP's ConvSC stacks (strides 1,2,1,2,...; v2 adds the first encoder layer to the last
decoder input instead of concatenating it). The translator sees (B, T*hid_s, h, w) and stacks `trans_layers`
MetaFormer blocks (OpenSTL's `MidMetaNet`): x + s1 * attention(BN(x)), x + s2 * MLP(BN(x)), 1x1 convolutions
to hid_t after the first block and back to T*hid_s after the last. The attention is TAU's temporal attention
unit: statical attention (a depthwise conv, a dilated depthwise conv and a 1x1 conv: large-kernel attention)
times dynamical attention (squeeze-excitation over channels of the average-pooled input) times the input.
"""

from __future__ import annotations

import torch
from torch import nn

from clods_bench.plugins.video.simvp_model import ConvSC, EncoderTranslatorDecoder, strides


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
        hidden = max(1, dim // max(dim // reduction, 4))  # OpenSTL's squeeze width
        self.fc = nn.Sequential(nn.Linear(dim, hidden, bias=False), nn.ReLU(), nn.Linear(hidden, dim, bias=False), nn.Sigmoid())

    def static(self, x: torch.Tensor) -> torch.Tensor:
        """Intra-frame statical attention (B,C,h,w): depthwise conv, dilated depthwise conv, 1x1 conv."""
        return self.conv1(self.conv_spatial(self.conv0(x)))

    def dynamical(self, x: torch.Tensor) -> torch.Tensor:
        """Inter-frame dynamical attention (B,C,1,1): sigmoid gates from the channels' spatial means."""
        return self.fc(x.mean(dim=(2, 3))).unsqueeze(-1).unsqueeze(-1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.static(x) * self.dynamical(x) * x


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
    """1x1 conv to dim*ratio, 3x3 depthwise conv, GELU, 1x1 conv back."""

    def __init__(self, dim: int, ratio: float) -> None:
        super().__init__()
        hidden = max(1, int(dim * ratio))
        self.net = nn.Sequential(nn.Conv2d(dim, hidden, 1), nn.Conv2d(hidden, hidden, 3, padding=1, groups=hidden), nn.GELU(), nn.Conv2d(hidden, dim, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class TauBlock(nn.Module):
    """MetaFormer block with TAU attention and layer scales (init 0.01); a 1x1 conv when c_in != c_out."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, mlp_ratio: float) -> None:
        super().__init__()
        self.norm1, self.norm2 = nn.BatchNorm2d(c_in), nn.BatchNorm2d(c_in)
        self.attn = TemporalAttention(c_in, kernel_size)
        self.mlp = MixMlp(c_in, mlp_ratio)
        self.scale1 = nn.Parameter(torch.full((c_in, 1, 1), 1e-2))
        self.scale2 = nn.Parameter(torch.full((c_in, 1, 1), 1e-2))
        self.reduction: nn.Module = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.scale1 * self.attn(self.norm1(x))
        x = x + self.scale2 * self.mlp(self.norm2(x))
        return self.reduction(x)


class TAU(EncoderTranslatorDecoder):
    """(B,T,3,H,W) frames in [0,1] -> (B,T,3,H,W): the next T frames."""

    def __init__(self, frames: int, hid_s: int, hid_t: int, enc_layers: int, trans_layers: int, kernel_size: int, mlp_ratio: float) -> None:
        super().__init__()
        st = strides(enc_layers)
        self.enc = nn.ModuleList(ConvSC(3 if i == 0 else hid_s, hid_s, s) for i, s in enumerate(st))
        widths = [frames * hid_s] + [hid_t] * (trans_layers - 1) + [frames * hid_s]
        self.translator = nn.Sequential(*(TauBlock(widths[i], widths[i + 1], kernel_size, mlp_ratio) for i in range(trans_layers)))
        self.dec = nn.ModuleList(ConvSC(hid_s, hid_s, s, transpose=True) for s in reversed(st))
        self.readout = nn.Conv2d(hid_s, 3, 1)

    def merge_skip(self, z: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        """SimVP v2 (TAU) adds the first encoder layer's output to the decoded features."""
        return z + skip


def differential_divergence(pred: torch.Tensor, truth: torch.Tensor, temperature: float = 0.1) -> torch.Tensor:
    """TAU's regulariser: KL(softmax_t(dpred/tau) || softmax_t(dtruth/tau)) of the frame differences (B,T-1,...),
    softmax over the T-1 differences of each pixel and channel, mean over all elements (0 for T < 3)."""
    if pred.shape[1] < 3:
        return pred.new_zeros(())
    dp = (pred[:, 1:] - pred[:, :-1]) / temperature
    dt = (truth[:, 1:] - truth[:, :-1]) / temperature
    log_p, log_q = torch.log_softmax(dp, dim=1), torch.log_softmax(dt, dim=1)
    return (log_p.exp() * (log_p - log_q)).mean()
