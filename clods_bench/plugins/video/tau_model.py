"""The TAU network (Tan et al. CVPR 2023, "Temporal Attention Unit") and its differential divergence regulariser, as in
the authors' code (OpenSTL: `SimVP_Model` with model_type 'tau', and `TAU.diff_div_reg`).

SimVP v2's encoder and decoder (`simvp2_codec.py`) around a translator that sees (B, T*hid_s, h, w) and stacks
`trans_layers` TAU blocks (`tau_blocks.py`): the first maps T*hid_s channels to hid_t, the last back.
"""

from __future__ import annotations

import torch
from torch import nn

from clods_bench.plugins.video.simvp2_codec import decoder, encoder
from clods_bench.plugins.video.simvp_model import EncoderTranslatorDecoder
from clods_bench.plugins.video.tau_blocks import TauBlock, drop_path_rates


class TAU(EncoderTranslatorDecoder):
    """(B,T,3,H,W) frames in [0,1] -> (B,T,3,H,W): the next T frames. `enc_layers` even, `trans_layers` >= 2."""

    def __init__(
        self, frames: int, hid_s: int, hid_t: int, enc_layers: int, trans_layers: int, kernel_size: int, mlp_ratio: float, drop_path: float = 0.0
    ) -> None:
        super().__init__()
        self.enc = encoder(3, hid_s, enc_layers)
        widths = [frames * hid_s] + [hid_t] * (trans_layers - 1) + [frames * hid_s]
        rates = drop_path_rates(trans_layers, drop_path)
        self.translator = nn.Sequential(*(TauBlock(widths[i], widths[i + 1], kernel_size, mlp_ratio, rates[i]) for i in range(trans_layers)))
        self.dec = decoder(hid_s, enc_layers)
        self.readout = nn.Conv2d(hid_s, 3, 1)

    def merge_skip(self, z: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        """SimVP v2 (TAU) adds the first encoder layer's output to the decoded features."""
        return z + skip


def differential_divergence(pred: torch.Tensor, truth: torch.Tensor, temperature: float = 0.1, eps: float = 1e-12) -> torch.Tensor:
    """TAU's regulariser on (B,T,...) frames, as its authors compute it: the frame differences (B,T-1,D) of each video,
    D = C*H*W, softmax over D of difference/temperature for prediction (p) and truth (q), then the mean over all
    B*(T-1)*D terms of p * log(p / (q + eps) + eps). 0 for T < 3, as theirs."""
    b, t = pred.shape[:2]
    if t <= 2:
        return pred.new_zeros(())
    dp = (pred[:, 1:] - pred[:, :-1]).reshape(b, t - 1, -1)
    dq = (truth[:, 1:] - truth[:, :-1]).reshape(b, t - 1, -1)
    p, q = torch.softmax(dp / temperature, dim=-1), torch.softmax(dq / temperature, dim=-1)
    return (p * torch.log(p / (q + eps) + eps)).mean()
