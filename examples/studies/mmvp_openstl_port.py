"""How OpenSTL's MMVP port differs from clods-bench's MMVP (the authors' network): same weights, float64.

The reference is github.com/chengtan9907/OpenSTL at commit c74deb5d4c3da585291f9f18281f3fefdbba3a54 (a git
checkout, given as the argument); only its three MMVP files are loaded (openstl/models/mmvp_model.py,
openstl/modules/mmvp_modules.py, openstl/utils/mmvp_utils.py), not the package. OpenSTL's port has the authors'
network with three changes, each measured here: its enhancer is hid_S channels wide (the authors': base_channel / 2;
clods-bench's enhancer is widened to match for this comparison), it reads frames unshifted (clods-bench's
pixel_offset is set to 0 here), and its last line reshapes the (N, H, W, C) output as (B, T, C, H, W), which
scrambles pixels and channels of a multi-channel frame (Moving MNIST and KTH are one channel, where it is
harmless). Checked for one channel (must agree) and for RGB (agrees only after clods-bench's output is scrambled
the same way), in eval mode and in train mode (loss and gradients).

    python examples/studies/mmvp_openstl_port.py /path/to/OpenSTL --out results/studies/mmvp_same_weights/openstl_port.txt
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import types
from pathlib import Path
from typing import Any

import torch
from torch import nn

from clods_bench.plugins.video.mmvp_blocks import RRDB
from clods_bench.plugins.video.mmvp_model import MMVP

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mmvp_same_weights import reference_name  # noqa: E402 - the authors' names, shared with that study
from same_weights_common import emit, fail, reference_args  # noqa: E402

REFERENCE = "github.com/chengtan9907/OpenSTL"
COMMIT = "c74deb5d4c3da585291f9f18281f3fefdbba3a54"
FILES = {"modules": "openstl/modules/mmvp_modules.py", "utils": "openstl/utils/mmvp_utils.py", "models": "openstl/models/mmvp_model.py"}
RENAME = [("encoder.", "enc."), ("filter_block_proj.", "filter.filter_block."), ("predictor.in_conv.", "hid.predictor.conv1."),
          ("predictor.out_conv.", "hid.predictor.out_conv."), ("predictor.predictor.", "hid.predictor.predictor."),
          ("decoder.outc.conv.", "dec.outc."), ("decoder.", "dec."), ("enhancer.outconv.conv.", "enhance.outconv."),
          ("enhancer.model.", "enhance.model.")]  # fmt: skip
UNUSED = ("hid.scale_fuser_1.", "hid.scale_fuser_2.", "hid.predictor.fuse_conv.")
CONFIG = dict(frames=4, side=32, channels=8, predictor_channels=4, blocks=1, batch=2)


def load_port(path: Path) -> Any:
    """OpenSTL's `MMVP_Model` from its three files, under stand-in `openstl.*` packages."""
    head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0 or head.stdout.strip() != COMMIT:
        fail(f"{path}: checkout is at {head.stdout.strip() or 'no git commit'}, this study knows {REFERENCE} at {COMMIT}")
    for key, rel in FILES.items():
        if not (path / rel).is_file():
            fail(f"{path / rel}: missing from the checkout")
        for pkg in ("openstl", f"openstl.{key}"):
            sys.modules.setdefault(pkg, types.ModuleType(pkg))
        spec = importlib.util.spec_from_file_location(f"openstl.{key}.mmvp", path / rel)
        module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        spec.loader.exec_module(module)  # type: ignore[union-attr]
        sys.modules[f"openstl.{key}"].__dict__.update({k: v for k, v in vars(module).items() if not k.startswith("_")})
    return sys.modules["openstl.models"].MMVP_Model


def port_name(name: str, blocks: int) -> str:
    target = reference_name(name, blocks)
    for old, new in RENAME:
        if target.startswith(old):
            return new + target[len(old) :]
    raise ValueError(name)


def build_pair(model_cls: Any, image_channels: int) -> tuple[MMVP, Any]:
    c = CONFIG
    torch.manual_seed(0)
    n, blocks = c["channels"], c["blocks"]
    mine = MMVP(c["frames"], n, c["predictor_channels"], (2, 2, 2), blocks, blocks, blocks, image_channels=image_channels, pixel_offset=0.0)
    mine.enhancer = nn.Sequential(nn.Conv2d(2 * image_channels, n, 3, padding=1), *(RRDB(n) for _ in range(blocks)), nn.Conv2d(n, image_channels, 1))
    mine = mine.double()
    port = model_cls((c["frames"], image_channels, c["side"], c["side"]), aft_seq_length=c["frames"], hid_S=n, hid_T=c["predictor_channels"],
                     rrdb_encoder_num=blocks, rrdb_decoder_num=blocks, rrdb_enhance_num=blocks).double()  # fmt: skip
    with torch.no_grad():
        for mod in mine.modules():
            if isinstance(mod, nn.modules.batchnorm._BatchNorm):
                mod.weight.uniform_(0.5, 1.5), mod.bias.normal_(0.0, 0.2), mod.running_mean.normal_(0.0, 0.2), mod.running_var.uniform_(0.5, 2.0)
    theirs = port.state_dict()
    mapped = {}
    for name, tensor in mine.state_dict().items():
        target = port_name(name, blocks)
        if target not in theirs or theirs[target].shape != tensor.shape:
            fail(f"clods-bench tensor {name} {tuple(tensor.shape)}: OpenSTL has no tensor {target} of that shape")
        mapped[target] = tensor
    left = [k for k in theirs if k not in mapped and not k.startswith(UNUSED)]
    if left:
        fail(f"OpenSTL tensor {left[0]}: not mapped from clods-bench's model")
    port.load_state_dict({**theirs, **mapped})
    return mine, port


def scrambled(out: torch.Tensor) -> torch.Tensor:
    """clods-bench's (B,F,C,H,W) output put through OpenSTL's last reshape ((N,C,H,W) -> (N,H,W,C) read as (B,F,C,H,W))."""
    return out.flatten(0, 1).permute(0, 2, 3, 1).reshape(out.shape)


def compare(model_cls: Any, image_channels: int) -> list[str]:
    mine, port = build_pair(model_cls, image_channels)
    c, p = CONFIG, CONFIG["frames"]
    window = torch.rand(c["batch"], 2 * p, image_channels, c["side"], c["side"], generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    lines = [f"{image_channels} channel(s), config {c}:"]
    mine.eval(), port.eval()
    with torch.no_grad():
        a, r = mine(window[:, :p]), port(window[:, :p])
    lines.append(f"  eval: max |out - OpenSTL| = {(a - r).abs().max().item():.3e}; after OpenSTL's reshape: {(scrambled(a) - r).abs().max().item():.3e}")
    mine.train(), port.train()
    la = nn.functional.mse_loss(scrambled(mine(window)), window[:, p:])
    lr = nn.functional.mse_loss(port(window), window[:, p:])
    la.backward(), lr.backward()
    theirs = dict(port.named_parameters())
    grad = max((t.grad - theirs[port_name(n, c["blocks"])].grad).abs().max().item() for n, t in mine.named_parameters())
    lines.append(f"  train (both through OpenSTL's reshape): loss |diff| = {abs(la.item() - lr.item()):.3e} (loss {lr.item():.6f}); max |grad diff| = {grad:.3e}")
    return lines


def main() -> None:
    args = reference_args(__doc__, REFERENCE, COMMIT)
    model_cls = load_port(args.reference)
    lines = [f"reference: {REFERENCE} at {COMMIT} (its MMVP files only); torch {torch.__version__}; float64"]
    for channels in (1, 3):
        lines += compare(model_cls, channels)
    emit(lines, args.out)


if __name__ == "__main__":
    main()
