"""Is clods-bench's MMVP the authors' MMVP? Same weights, same frames, float64: outputs, loss and gradients.

The reference is the authors' code, github.com/Kay1794/MMVP-motion-matrix-based-video-prediction at commit
ebf84bb849dba80bdca5c40b76a6774fe4ec5c31 (a git checkout, given as the argument). Its `Model` is built with the
options of its README command and its Moving MNIST / KTH advice (`--filter_block --res_cat_img --scale_in_use 3
--use_direct_predictor`, translate_factor 1, prev_len = fut_len = P, RGB frames); every tensor of clods-bench's
model is copied into it one to one (random weights, random BatchNorm affine parameters and running statistics).
Only the model modules are imported; modules they import for training and plotting but do not use in the model
(lpips, whose import builds a pretrained AlexNet from the network, and cv2, h5py, torchvision where absent) are
replaced by empty stand-ins. Checked, per configuration:

- eval mode: the prediction from P frames (the reference gets the frames shifted by -0.5, as its data loader
  shifts them; clods-bench shifts inside the model) and from 2P frames (the extra frames must change nothing);
- train mode, as both train: the 2P-frame window in, MSE of the P predicted frames against the last P; the
  loss, the gradient of every parameter and the BatchNorm running statistics after the step.

    python examples/studies/mmvp_same_weights.py /path/to/MMVP-motion-matrix-based-video-prediction \
        --out results/studies/mmvp_same_weights/differences.txt
"""

from __future__ import annotations

import importlib
import re
import sys
import types
from pathlib import Path
from typing import Any

import torch

from clods_bench.plugins.video.mmvp_model import MMVP

sys.path.insert(0, str(Path(__file__).resolve().parent))
from same_weights_common import check_checkout, emit, fail, reference_args  # noqa: E402

REFERENCE = "github.com/Kay1794/MMVP-motion-matrix-based-video-prediction"
COMMIT = "ebf84bb849dba80bdca5c40b76a6774fe4ec5c31"
UNUSED = ("scale_fuser_1.", "scale_fuser_2.", "predictor.fuse_conv.")
"""Reference parameters its forward never reads (built by `Model.__init__`, used by no branch of these options)."""
CONFIGS = [  # (frames P, image side, channels, predictor channels, factors, RRDBs in encoder/decoder/enhancer, batch)
    dict(frames=5, side=64, channels=16, predictor_channels=8, downsample=(2, 2, 2), blocks=2, batch=2),
    dict(frames=3, side=64, channels=8, predictor_channels=4, downsample=(2, 4, 2), blocks=1, batch=2),
]


def import_reference(path: Path) -> Any:
    """The reference's `model` module, with empty stand-ins for the packages its imports need but its model does not."""
    absent = {n for n in ("cv2", "h5py", "torchvision") if importlib.util.find_spec(n) is None} | {"lpips"}
    for name in ("lpips", "cv2", "h5py", "torchvision", "torchvision.models", "torchvision.models.resnet"):
        if name.split(".")[0] not in absent:
            continue
        stub = types.ModuleType(name)
        stub.__all__ = []  # type: ignore[attr-defined]
        stub.LPIPS = lambda **kw: None  # type: ignore[attr-defined]
        sys.modules[name] = stub
    sys.path.insert(0, str(path))
    module = importlib.import_module("model")
    if Path(module.__file__).resolve().parent != path.resolve():
        fail(f"{module.__file__}: imported instead of {path / 'model.py'}")
    return module


def reference_config(c: dict[str, Any]) -> dict[str, Any]:
    """The authors' config dict for one configuration (main.py's keys, README options)."""
    ds, side = list(c["downsample"]), c["side"]
    high, low = 2 * ds[0] * ds[1], 2 * ds[0] * ds[1] * ds[2]
    return {
        "prev_len": c["frames"], "fut_len": c["frames"], "long_term": False, "n_channel": 3, "shuffle_setting": True,
        "bilinear": False, "base_channel": c["channels"], "pred_base_channel": c["predictor_channels"], "translate_factor": 1,
        "filter_block": True, "res_cat_img": True, "res_img_scale": 1, "scale_in_use": "3", "use_direct_predictor": True,
        "pred_type": "highonly", "use_bn": False, "motion_use_bn": True, "downsample_scale": ds, "loss_list": ["recon"],
        "rrdb_encoder_num": c["blocks"], "rrdb_decoder_num": c["blocks"], "rrdb_enhance_num": c["blocks"],
        "mat_size": [[side // high, side // high], [side // low, side // low]],
    }  # fmt: skip


def reference_name(name: str, blocks: int) -> str:
    """The reference's name of one of clods-bench's tensors (ValueError when there is no rule for it)."""
    rdb = r"blocks\.(\d)\.convs\.(\d)\.(.+)$"
    sub = lambda m, g: f"RDB{int(m.group(g)) + 1}.conv{int(m.group(g + 1)) + 1}.{m.group(g + 2)}"  # noqa: E731
    pred = {"embed": "in_conv", "readout": "out_conv", "translate": "predictor.conv_translate.0", "translate_norm": "predictor.bn_translate"}
    layer = {"pre.0": ("conv_pre_1", "bn_pre_1"), "pre.1": ("conv_pre_2", "bn_pre_2"), "down1": ("conv1_1", "bn1_1"),
             "down2": ("conv2_1", "bn2_1"), "up1": ("conv3_1", "bn3_1"), "up2": ("conv4_1", "bn4_1"),
             "time1": ("conv3d_1.conv3d", "conv3d_1.bn3d"), "time2": ("temporal_layer.conv3d", "temporal_layer.bn3d")}  # fmt: skip
    downs = ("pre_downsample_block.0", "downsample_high", "downsample_low")
    ups = ("upsample_block_low2high", "upsample_block.0", "upsample_block.1")
    rules: list[tuple[str, Any]] = [
        (r"^stem\.0\.(.+)$", lambda m: f"encoder.inconv.{m.group(1)}"),
        (r"^stem\.(\d+)\." + rdb, lambda m: f"encoder.block_rrdb.{int(m.group(1)) - 1}.{sub(m, 2)}"),
        (r"^down\.(\d)\.(.+)$", lambda m: f"encoder.{downs[int(m.group(1))]}.{m.group(2)}"),
        (r"^filter_(fine|coarse)\.(\d)\.(conv|norm)\.(.+)$",
         lambda m: f"filter_block_proj.{int(m.group(1) == 'coarse')}.{3 * int(m.group(2)) + int(m.group(3) == 'norm')}.{m.group(4)}"),
        (r"^predictor\.(embed|readout|translate|translate_norm)\.(.+)$", lambda m: f"predictor.{pred[m.group(1)]}.{m.group(2)}"),
        (r"^predictor\.(pre\.\d|down\d|up\d|time\d)\.(conv|norm)\.(.+)$",
         lambda m: f"predictor.predictor.{layer[m.group(1)][m.group(2) == 'norm']}.{m.group(3)}"),
        (r"^up\.(\d)\.up\.(.+)$", lambda m: f"decoder.{ups[int(m.group(1))]}.up.{m.group(2)}"),
        (r"^up\.(\d)\.conv\.(.+)$", lambda m: f"decoder.{ups[int(m.group(1))]}.conv.conv.0.{m.group(2)}"),
        (rf"^dec\.{blocks}\.(.+)$", lambda m: f"decoder.outc.conv.{m.group(1)}"),
        (r"^dec\.(\d+)\." + rdb, lambda m: f"decoder.rrdb_block.{m.group(1)}.{sub(m, 2)}"),
        (r"^enhancer\.0\.(.+)$", lambda m: f"enhancer.model.0.{m.group(1)}"),
        (rf"^enhancer\.{blocks + 1}\.(.+)$", lambda m: f"enhancer.outconv.conv.{m.group(1)}"),
        (r"^enhancer\.(\d+)\." + rdb, lambda m: f"enhancer.model.{m.group(1)}.{sub(m, 2)}"),
    ]
    for pattern, rewrite in rules:
        if (m := re.match(pattern, name)) is not None:
            return rewrite(m)
    raise ValueError(name)


def build_pair(ref_module: Any, c: dict[str, Any]) -> tuple[MMVP, Any, dict[str, str]]:
    """clods-bench's model with random weights and BatchNorm state, the reference with the same, and the name map."""
    torch.manual_seed(0)
    mine = MMVP(c["frames"], c["channels"], c["predictor_channels"], c["downsample"], c["blocks"], c["blocks"], c["blocks"]).double()
    ref = ref_module.Model(reference_config(c)).double()
    with torch.no_grad():
        for name, mod in mine.named_modules():
            if isinstance(mod, torch.nn.modules.batchnorm._BatchNorm):
                mod.weight.uniform_(0.5, 1.5), mod.bias.normal_(0.0, 0.2)
                mod.running_mean.normal_(0.0, 0.2), mod.running_var.uniform_(0.5, 2.0)
    theirs = ref.state_dict()
    names: dict[str, str] = {}
    for name, tensor in mine.state_dict().items():
        try:
            target = reference_name(name, c["blocks"])
        except ValueError:
            fail(f"clods-bench tensor {name}: no rule maps it to a tensor of the reference")
        if target not in theirs or theirs[target].shape != tensor.shape:
            fail(f"clods-bench tensor {name} {tuple(tensor.shape)}: reference has no tensor {target} of that shape")
        names[name] = target
    left = sorted(set(theirs) - set(names.values()))
    if any(not n.startswith(UNUSED) for n in left):
        fail(f"reference tensor {next(n for n in left if not n.startswith(UNUSED))}: not mapped from clods-bench's model")
    ref.load_state_dict({**theirs, **{names[k]: v for k, v in mine.state_dict().items()}})
    return mine, ref, names


def run_reference(ref: Any, frames: torch.Tensor) -> torch.Tensor:
    """(B,F,C,H,W) prediction of the reference from frames (B,T,C,H,W) in [0, 1] (it reads them shifted, channels last)."""
    b, _, c, h, w = frames.shape
    out = ref((frames - 0.5).permute(0, 1, 3, 4, 2), inference=not ref.training)["recon_img"]
    return out.reshape(b, -1, h, w, c).permute(0, 1, 4, 2, 3) + 0.5


def compare(ref_module: Any, c: dict[str, Any]) -> list[str]:
    """Lines of max differences for one configuration."""
    mine, ref, names = build_pair(ref_module, c)
    p, side = c["frames"], c["side"]
    window = torch.rand(c["batch"], 2 * p, 3, side, side, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    lines = [f"config {c}: {sum(t.numel() for t in mine.parameters())} parameters mapped; unused in the reference: "
             f"{sum(t.numel() for n, t in ref.named_parameters() if n.startswith(UNUSED))} ({', '.join(UNUSED)})"]  # fmt: skip
    mine.eval(), ref.eval()
    with torch.no_grad():
        for t in (p, 2 * p):
            a, r = mine(window[:, :t]), run_reference(ref, window[:, :t])
            lines.append(f"  eval, {t} frames in: max |out - ref| = {(a - r).abs().max().item():.3e} (outputs up to {r.abs().max().item():.3f})")
    mine.train(), ref.train()
    target = window[:, p:]
    la = torch.nn.functional.mse_loss(mine(window), target)
    lr = torch.nn.functional.mse_loss(run_reference(ref, window), target)
    la.backward(), lr.backward()
    theirs = dict(ref.named_parameters())
    grad = max((p_.grad - theirs[names[n]].grad).abs().max().item() for n, p_ in mine.named_parameters())
    scale = max(p_.grad.abs().max().item() for p_ in mine.parameters())
    unused = [n for n, t in theirs.items() if n.startswith(UNUSED) and t.grad is not None and t.grad.abs().max() > 0]
    buffers = dict(ref.named_buffers())
    stats = max((b_.double() - buffers[names[n]].double()).abs().max().item() for n, b_ in mine.named_buffers())
    lines += [
        f"  train, {2 * p} frames in: loss {la.item():.12f} vs {lr.item():.12f}, |diff| = {abs(la.item() - lr.item()):.3e}",
        f"  train: max |grad - ref grad| over all {len(names)} tensors' parameters = {grad:.3e} (gradients up to {scale:.3e}); "
        f"reference's unused parameters with a gradient: {unused or 'none'}",
        f"  train: max |BatchNorm running stats - ref| after the step = {stats:.3e}",
    ]
    return lines


def main() -> None:
    args = reference_args(__doc__, REFERENCE, COMMIT)
    check_checkout(args.reference, "model.py", REFERENCE, COMMIT)
    ref_module = import_reference(args.reference)
    lines = [f"reference: {REFERENCE} at {COMMIT}; torch {torch.__version__}; float64"]
    for c in CONFIGS:
        lines += compare(ref_module, c)
    emit(lines, args.out)


if __name__ == "__main__":
    main()
