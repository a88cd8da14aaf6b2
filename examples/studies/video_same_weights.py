"""SimVP (v1), TAU and MAU against their authors' code with the same weights, in float64.

Each network is built at the `ci` preset's widths (5 -> 5 frames of 64x64 px, batch 2), its weights moved away from
their initial values and copied one to one into the reference network; then outputs (eval mode), training losses
and their parameter gradients (train mode: BatchNorm batch statistics; TAU's stochastic depth from the same torch
seed; MAU's scheduled-sampling input from one mask), TAU's regulariser (value and gradient) and MAU's
scheduled-sampling probabilities are compared, and the parameter counts. References (checkouts at the commits in
`video_references.KNOWN`):

- SimVP (v1): A4Bio/SimVP `model.SimVP`, the code of the paper the CloDS paper cites.
- TAU: OpenSTL `SimVP_Model(model_type='tau')` and `TAU.diff_div_reg`, the TAU authors' code.
- MAU: ZhengChang467/MAU `core.models.MAU.RNN` and `MAU_run.schedule_sampling` (the authors'), and OpenSTL `MAU_Model`.

    python examples/studies/video_same_weights.py --openstl DIR --simvp DIR --mau DIR --out FILE.json

The Python that runs it needs torch and numpy, and for OpenSTL timm (which imports torchvision's Python modules) and
scipy; run it from the repository root, or with clods_bench importable.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch
import yaml
from video_references import (
    KNOWN,
    StudyError,
    check_checkout,
    function_from_source,
    grad_diff,
    import_from,
    map_state,
    max_diff,
    need_file,
    randomize,
)

from clods_bench.plugins.video.mau import MauConfig, MauPredictor
from clods_bench.plugins.video.simvp import SimvpConfig, SimvpPredictor
from clods_bench.plugins.video.tau import TauConfig, TauPredictor
from clods_bench.plugins.video.tau_model import differential_divergence

B, T, H = 2, 5, 64
PRESET = Path(__file__).resolve().parents[2] / "clods_bench/benchmark/core/presets/ci.yaml"


def ci_config(name: str, cls: type) -> Any:
    """The ci preset's video_config.<name> as its config dataclass."""
    return cls(**yaml.safe_load(PRESET.read_text())["video_config"][name])


def data(seed: int, frames: int) -> torch.Tensor:
    """(B, frames, 3, H, H) float64 in [0, 1)."""
    return torch.from_numpy(np.random.default_rng(seed).random((B, frames, 3, H, H)))


def cpu_name() -> str:
    """The CPU's model name (Linux), else the machine type."""
    info = Path("/proc/cpuinfo")
    lines = info.read_text().splitlines() if info.is_file() else []
    return next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")), platform.machine())


def count(model: torch.nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


ENCODER_DECODER = [
    (r"enc\.(\d+)\.(conv|norm)\.(.+)", r"enc.enc.\1.conv.\2.\3"),
    (r"dec\.(\d+)\.(conv|norm)\.(.+)", r"dec.dec.\1.conv.\2.\3"),
    (r"readout\.(.+)", r"dec.readout.\1"),
]
"""Our encoder/decoder tensor names -> SimVP's and OpenSTL's (the same layout in both references)."""


def study_simvp(root: Path) -> dict[str, Any]:
    need_file(root, "model.py")
    ref_mod = import_from(root, "model")
    cfg = ci_config("simvp", SimvpConfig)
    torch.manual_seed(0)
    ours = SimvpPredictor(cfg).build_model().double()
    ref = ref_mod.SimVP((T, 3, H, H), cfg.hid_s, cfg.hid_t, cfg.enc_layers, cfg.trans_layers, list(cfg.kernels), cfg.groups).double()
    randomize(ours, 1)
    names, _ = map_state(ours, ref, [
        *ENCODER_DECODER,
        (r"translator\.(enc|dec)\.(\d+)\.conv1\.(.+)", r"hid.\1.\2.conv1.\3"),
        (r"translator\.(enc|dec)\.(\d+)\.branches\.(\d+)\.(conv|norm)\.(.+)", r"hid.\1.\2.layers.\3.\4.\5"),
    ])  # fmt: skip
    x, y = data(2, T), data(3, T)
    out = {"parameters": count(ours), "reference_parameters": count(ref)}
    with torch.no_grad():
        out["output_max_diff"] = max_diff(ours.eval()(x), ref.eval()(x))
    losses = [torch.nn.functional.mse_loss(m.train()(x), y) for m in (ours, ref)]
    for loss in losses:
        loss.backward()
    out["loss_diff"] = abs(losses[0].item() - losses[1].item())
    out["grad_max_diff"], out["grad_scale"] = grad_diff(ours, ref, names)
    return out


def tau_reference_loss(root: Path) -> Any:
    env = {"torch": torch, "F": torch.nn.functional}
    return function_from_source(need_file(root, "openstl/methods/tau.py"), "diff_div_reg", env, cls="TAU")


def study_tau(root: Path) -> dict[str, Any]:
    need_file(root, "openstl/models/simvp_model.py")
    ref_mod = import_from(root, "openstl.models.simvp_model", stub_packages=("openstl", "openstl.models"))
    ref_reg = tau_reference_loss(root)
    cfg = ci_config("tau", TauConfig)
    pred = TauPredictor(cfg)
    torch.manual_seed(0)
    ours = pred.build_model().double()
    ref = ref_mod.SimVP_Model((T, 3, H, H), hid_S=cfg.hid_s, hid_T=cfg.hid_t, N_S=cfg.enc_layers, N_T=cfg.trans_layers, model_type="tau",
                              mlp_ratio=cfg.mlp_ratio, drop=0.0, drop_path=cfg.drop_path).double()  # fmt: skip
    if cfg.kernel_size != 21:
        raise StudyError(f"OpenSTL's TAU attention is 21 px; the ci preset's video_config.tau.kernel_size is {cfg.kernel_size}")
    randomize(ours, 1)
    names, _ = map_state(ours, ref, [
        *ENCODER_DECODER,
        (r"translator\.(\d+)\.reduction\.(.+)", r"hid.enc.\1.reduction.\2"),
        (r"translator\.(\d+)\.attn\.unit\.(.+)", r"hid.enc.\1.block.attn.spatial_gating_unit.\2"),
        (r"translator\.(\d+)\.mlp\.dwconv\.(.+)", r"hid.enc.\1.block.mlp.dwconv.dwconv.\2"),
        (r"translator\.(\d+)\.(.+)", r"hid.enc.\1.block.\2"),
    ])  # fmt: skip
    x, window = data(2, T), data(3, 2 * T)
    out: dict[str, Any] = {"parameters": count(ours), "reference_parameters": count(ref)}
    with torch.no_grad():
        out["output_max_diff"] = max_diff(ours.eval()(x), ref.eval()(x))
    losses = []
    for model in (ours, ref):
        torch.manual_seed(7)  # the same stochastic-depth draws
        model.train()
        if model is ours:
            losses.append(pred.loss(model, window, 0, np.random.default_rng(0)))
        else:
            p = model(window[:, :T].contiguous())
            losses.append(torch.nn.functional.mse_loss(p, window[:, T:]) + cfg.alpha * ref_reg(None, p, window[:, T:]))
        losses[-1].backward()
    out["train_loss"] = losses[0].item()
    out["train_loss_diff"] = abs(losses[0].item() - losses[1].item())
    out["grad_max_diff"], out["grad_scale"] = grad_diff(ours, ref, names)
    out["regulariser"] = regulariser(ref_reg, cfg)
    return out


def regulariser(ref_reg: Any, cfg: TauConfig) -> dict[str, Any]:
    """TAU's regulariser against the reference's on two pairs: independent random frames, and a prediction 0.05 of
    noise away from a moving pattern; value, gradient, and alpha x |gradient| over the MSE's."""
    g = np.random.default_rng(4)
    yy, xx = np.meshgrid(np.arange(H), np.arange(H), indexing="ij")
    moving = np.stack([0.5 + 0.4 * np.sin((xx - 3 * t) / 6.0 + yy / 9.0) for t in range(T)])[None, :, None].repeat(B, 0).repeat(3, 2)
    pairs = {"random": (g.random((B, T, 3, H, H)), g.random((B, T, 3, H, H))), "near": (moving + 0.05 * g.standard_normal(moving.shape), moving)}
    res = {}
    for name, (p_np, q_np) in pairs.items():
        q = torch.from_numpy(q_np)
        grads, values = [], []
        for fn in (lambda a, b: differential_divergence(a, b, cfg.temperature), lambda a, b: ref_reg(None, a, b)):
            p = torch.from_numpy(p_np).requires_grad_(True)
            v = fn(p, q)
            v.backward()
            values.append(v.item())
            grads.append(p.grad)
        p = torch.from_numpy(p_np).requires_grad_(True)
        torch.nn.functional.mse_loss(p, q).backward()
        res[name] = {"value": values[0], "value_diff": abs(values[0] - values[1]), "grad_max_diff": max_diff(grads[0], grads[1]),
                     "alpha_grad_over_mse_grad": cfg.alpha * float(grads[0].norm() / p.grad.norm())}  # fmt: skip
    return res


MAU_RULES = [
    (r"enc\.0\.0\.(.+)", r"encoders.0.encoder_t_conv-1.\1"),
    (r"enc\.(\d+)\.0\.(.+)", lambda m: f"encoders.{m[1]}.encoder_t{int(m[1]) - 1}.{m[2]}"),
    (r"cells\.(\d+)\.(.+)", r"cell_list.\1.\2"),
    (r"dec\.(\d+)\.0\.(.+)", r"decoders.\1.c_decoder\1.\2"),
    (r"dec\.(\d+)\.(weight|bias)", r"decoders.\1.c_decoder\1.\2"),
    (r"readout\.(.+)", r"srcnn.0.\1"),
]
MAU_UNUSED = (r"merge\..*", r"conv_last_sr\..*")  # 1x1 convs the references build and never call


def mau_compare(ours: torch.nn.Module, ref: torch.nn.Module, call_ref: Any) -> dict[str, Any]:
    """Eval outputs (9 steps, predictions fed back), and with a scheduled-sampling mask the training loss and its gradients."""
    names, unused = map_state(ours, ref, MAU_RULES, MAU_UNUSED)
    frames = data(5, 2 * T)
    mask = torch.from_numpy(np.random.default_rng(6).random((B, T - 1)) < 0.5)
    dense = mask.to(torch.float64)[:, :, None, None, None].expand(B, T - 1, H, H, 3)  # the references' (B, T-1, H, W, C) flags
    out: dict[str, Any] = {"parameters": count(ours), "reference_parameters": count(ref), "reference_unused": unused}
    with torch.no_grad():
        out["output_max_diff"] = max_diff(ours.eval()(frames[:, :T], T), call_ref(ref.eval(), frames, torch.zeros_like(dense)))
    losses = [torch.nn.functional.mse_loss(ours.train()(frames[:, :T], T, truth=frames[:, T:], use_truth=mask), frames[:, 1:]),
              torch.nn.functional.mse_loss(call_ref(ref.train(), frames, dense), frames[:, 1:])]  # fmt: skip
    for loss in losses:
        loss.backward()
    out["sampled_loss_diff"] = abs(losses[0].item() - losses[1].item())
    out["grad_max_diff"], out["grad_scale"] = grad_diff(ours, ref, names)
    return out


def study_mau(root: Path | None, openstl: Path | None) -> dict[str, Any]:
    cfg = ci_config("mau", MauConfig)
    pred = MauPredictor(cfg)
    pred.size = (H, H)
    shape = {"tau": cfg.tau, "cell_mode": "normal", "model_mode": "normal", "sr_size": 2**cfg.downsamples, "stride": 1, "patch_size": 1}
    res: dict[str, Any] = {}
    if root is not None:
        need_file(root, "core/models/MAU.py")
        rnn = import_from(root, "core.models.MAU").RNN
        conf = SimpleNamespace(**shape, img_channel=3, img_height=H, img_width=H, filter_size=(cfg.kernel, cfg.kernel), device="cpu",
                               input_length=T, total_length=2 * T)  # fmt: skip
        torch.manual_seed(0)
        ours = pred.build_model().double()
        randomize(ours, 1)
        ref = rnn(cfg.num_layers, [cfg.hidden] * cfg.num_layers, conf).double()
        res["authors"] = mau_compare(ours, ref, lambda m, f, mask: m(f, mask))
        res["authors"]["sampling"] = mau_schedule(root, pred)
    if openstl is not None:
        need_file(openstl, "openstl/models/mau_model.py")
        model = import_from(openstl, "openstl.models.mau_model", stub_packages=("openstl", "openstl.models")).MAU_Model
        conf = SimpleNamespace(**shape, in_shape=(T, 3, H, H), filter_size=cfg.kernel, pre_seq_length=T, total_length=2 * T)
        torch.manual_seed(0)
        ours = pred.build_model().double()
        randomize(ours, 1)
        ref = model(cfg.num_layers, [cfg.hidden] * cfg.num_layers, conf).double()
        res["openstl"] = mau_compare(ours, ref, lambda m, f, mask: m(f.permute(0, 1, 3, 4, 2), mask, return_loss=False)[0])
    return res


def mau_schedule(root: Path, pred: MauPredictor) -> dict[str, Any]:
    """The authors' `schedule_sampling` (true-frame probability eta) over their 80,000 iterations against ours."""
    args = SimpleNamespace(scheduled_sampling=True, sampling_stop_iter=50000, sampling_changing_rate=0.00002, total_length=2 * T,
                           input_length=T, img_height=4, img_width=4, patch_size=1)  # fmt: skip
    fn = function_from_source(need_file(root, "MAU_run.py"), "schedule_sampling", {"np": np, "args": args, "print": lambda *a: None})
    full = MauPredictor(MauConfig(**{**pred.cfg.__dict__, "train_steps": 80000}))
    eta, worst = 1.0, 0.0
    for itr in range(80001):
        eta, _ = fn(eta, itr, 1, 1)
        worst = max(worst, abs(eta - full.truth_probability(itr)))
    return {"iterations": 80001, "eta_max_diff": worst}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--openstl", type=Path, help=f"checkout of {KNOWN['openstl'][0]} at {KNOWN['openstl'][1]}")
    ap.add_argument("--simvp", type=Path, help=f"checkout of {KNOWN['simvp'][0]} at {KNOWN['simvp'][1]}")
    ap.add_argument("--mau", type=Path, help=f"checkout of {KNOWN['mau'][0]} at {KNOWN['mau'][1]}")
    ap.add_argument("--out", type=Path, help="write the differences here as JSON")
    a = ap.parse_args()
    if not (a.openstl or a.simvp or a.mau):
        ap.error("name at least one reference checkout")
    torch.set_default_dtype(torch.float64)  # the references make their zero states in the default dtype
    result: dict[str, Any] = {"references": {}, "dtype": "float64", "batch": B, "frames": T, "image": H, "widths": "ci preset",
                              "torch": torch.__version__, "cpu": cpu_name(), "date": datetime.date.today().isoformat()}  # fmt: skip
    try:
        roots = {k: check_checkout(k, getattr(a, k)) for k in ("openstl", "simvp", "mau") if getattr(a, k)}
        result["references"] = {k: {"repository": KNOWN[k][0], "commit": KNOWN[k][1]} for k in roots}
        if "simvp" in roots:
            result["simvp"] = study_simvp(roots["simvp"])
        if "openstl" in roots:
            result["tau"] = study_tau(roots["openstl"])
        if "mau" in roots or "openstl" in roots:
            result["mau"] = study_mau(roots.get("mau"), roots.get("openstl"))
    except StudyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = json.dumps(result, indent=2)
    print(text)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
