"""SimVP video predictor: trained on single-view videos with an MSE loss and Adam, predicts recursively.

Protocol (CloDS appendix, 'Dataset details'): the baseline "cannot utilize multi-view videos",
so every view of every training video is a separate single-view sample; windows of
2*`context_frames` consecutive frames give (input, target) pairs. Longer horizons are
predicted by feeding predicted blocks back in. Training resumes from `simvp.pt` in the
work directory when that checkpoint belongs to the same config and videos.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from rich.progress import Progress

from clods_bench.atomic import atomic_path
from clods_bench.benchmark.interfaces import FitContext, check_video
from clods_bench.errors import ClodsError
from clods_bench.threads import torch_threads
from clods_bench.plugins.video.simvp_model import SimVP, strides

CHECKPOINT_FILE = "simvp.pt"
CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class SimvpConfig:
    """Options of the SimVP predictor (`video_config.simvp.*`); defaults follow SimVP v1 at a small size."""

    context_frames: int = 10
    """Frames in and out of one network pass (SimVP: 10 -> 10); longer horizons are predicted recursively."""
    hid_s: int = 64
    """Channels of the per-frame encoder/decoder (SimVP: 64)."""
    hid_t: int = 256
    """Channels of the translator (SimVP: 256)."""
    enc_layers: int = 4
    """Encoder (and decoder) ConvSC layers, strides 1,2,1,2,... (SimVP: 4)."""
    trans_layers: int = 8
    """Inception blocks of the translator U-Net (SimVP: 8)."""
    kernels: list[int] = dataclasses.field(default_factory=lambda: [3, 5, 7, 11])
    """Kernel sizes of the Inception branches (SimVP: 3, 5, 7, 11)."""
    groups: int = 8
    """Groups of the Inception convolutions (SimVP: 8)."""
    train_steps: int = 2000
    """Adam steps."""
    batch_size: int = 16
    """Windows per step."""
    learning_rate: float = 1e-3
    """Adam learning rate (one-cycle schedule peaking at this value, as SimVP trains)."""
    checkpoint_every: int = 500
    """Steps between checkpoints (0: only at the end)."""
    num_threads: int = 0
    """torch CPU threads while training/predicting (0: leave torch's setting)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        for name in ("context_frames", "hid_s", "hid_t", "enc_layers", "trans_layers", "groups", "train_steps", "batch_size"):
            if getattr(self, name) < 1:
                raise ClodsError(f"must be >= 1, got {getattr(self, name)}", where=f"video_config.simvp.{name}")
        if self.hid_s % 2:
            raise ClodsError(f"must be even (GroupNorm with 2 groups), got {self.hid_s}", where="video_config.simvp.hid_s")
        if not self.kernels or any(k < 1 or k % 2 == 0 for k in self.kernels):
            raise ClodsError(f"must be odd sizes >= 1, got {self.kernels}", where="video_config.simvp.kernels")
        if self.learning_rate <= 0:
            raise ClodsError(f"must be > 0, got {self.learning_rate}", where="video_config.simvp.learning_rate")
        if self.checkpoint_every < 0 or self.num_threads < 0:
            raise ClodsError("checkpoint_every and num_threads must be >= 0", where="video_config.simvp")


def _digest(cfg: SimvpConfig, videos: Sequence[np.ndarray]) -> str:
    h = hashlib.sha256(json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode())
    for v in videos:
        h.update(str(v.shape).encode())
        h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()[:16]


class SimvpPredictor:
    """SimVP trained from scratch on the given single-view videos."""

    def __init__(self, cfg: SimvpConfig, seed: int = 0, progress: bool = True) -> None:
        cfg.validate()
        self.cfg, self.seed, self.progress = cfg, seed, progress
        self.model: SimVP | None = None
        self.size: tuple[int, int] | None = None

    def _build(self) -> SimVP:
        c = self.cfg
        torch.manual_seed(self.seed)
        return SimVP(c.context_frames, c.hid_s, c.hid_t, c.enc_layers, c.trans_layers, tuple(c.kernels), c.groups)

    def _check_size(self, h: int, w: int, where: str) -> None:
        factor = 2 ** sum(s == 2 for s in strides(self.cfg.enc_layers))
        if h % factor or w % factor:
            raise ClodsError(
                f"frames of {h}x{w} px cannot be downsampled {factor}x by {self.cfg.enc_layers} encoder layers",
                where=where,
                hint=f"use image sides divisible by {factor} or fewer video_config.simvp.enc_layers",
            )

    def fit(self, videos: Sequence[np.ndarray], ctx: FitContext) -> dict[str, float]:
        """Train on windows of 2*context_frames frames of every video; MSE, Adam, one-cycle LR; resumable."""
        c = self.cfg
        window = 2 * c.context_frames
        vids = [check_video(v, where=f"simvp.fit: video {i}") for i, v in enumerate(videos)]
        if not vids:
            raise ClodsError("no training videos", where="simvp.fit")
        sizes = {v.shape[1:3] for v in vids}
        if len(sizes) != 1:
            raise ClodsError(f"training videos have different frame sizes {sorted(sizes)}", where="simvp.fit")
        h, w = sizes.pop()
        self._check_size(h, w, "simvp.fit")
        starts = [(i, s) for i, v in enumerate(vids) for s in range(v.shape[0] - window + 1)]
        if not starts:
            longest = max(v.shape[0] for v in vids)
            raise ClodsError(
                f"videos of at most {longest} frames are shorter than one training window of {window} (2 x context_frames)",
                where="simvp.fit",
                hint="lower video_config.simvp.context_frames",
            )
        data = [torch.from_numpy(np.ascontiguousarray(v.transpose(0, 3, 1, 2))) for v in vids]  # (T,3,H,W)
        self.size = (h, w)
        model = self._build()
        opt = torch.optim.Adam(model.parameters(), lr=c.learning_rate)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=c.learning_rate, total_steps=c.train_steps)
        path = Path(ctx.work_dir) / CHECKPOINT_FILE
        digest = _digest(c, vids)
        step, losses = 0, []
        if path.is_file():
            step, losses = self._resume(path, digest, model, opt, sched)
        rng = np.random.default_rng(ctx.seed + 1000 * step)
        t0 = time.perf_counter()
        with torch_threads(c.num_threads or None), Progress(transient=True, disable=not (ctx.progress and self.progress)) as bar:
            job = bar.add_task("simvp training", total=c.train_steps, completed=step)
            model.train()
            while step < c.train_steps:
                pick = rng.integers(len(starts), size=c.batch_size)
                batch = torch.stack([data[starts[k][0]][starts[k][1] : starts[k][1] + window] for k in pick])
                x, y = batch[:, : c.context_frames], batch[:, c.context_frames :]
                loss = torch.nn.functional.mse_loss(model(x), y)
                opt.zero_grad()
                loss.backward()
                opt.step()
                sched.step()
                losses.append(loss.item())
                step += 1
                bar.update(job, completed=step, description=f"simvp training (mse {np.mean(losses[-20:]):.2e})")
                if (c.checkpoint_every and step % c.checkpoint_every == 0) or step == c.train_steps:
                    self._save(path, digest, step, losses, model, opt, sched)
        self.model = model.eval()
        k = max(1, min(20, len(losses) // 10))
        return {
            "train_seconds": time.perf_counter() - t0,
            "train_steps": float(c.train_steps),
            "train_windows": float(len(starts)),
            "initial_loss": float(np.mean(losses[:k])),
            "final_loss": float(np.mean(losses[-k:])),
            "parameters": float(sum(p.numel() for p in model.parameters())),
        }

    def _save(self, path: Path, digest: str, step: int, losses: list[float], model: SimVP, opt: Any, sched: Any) -> None:
        payload = {
            "format": CHECKPOINT_FORMAT,
            "digest": digest,
            "step": step,
            "losses": losses,
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
        }
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)

    def _resume(self, path: Path, digest: str, model: SimVP, opt: Any, sched: Any) -> tuple[int, list[float]]:
        hint = "delete it (or use another work directory) to train from scratch"
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same clear message
            raise ClodsError(f"unreadable SimVP checkpoint ({type(exc).__name__}: {exc})", where=str(path), hint=hint) from None
        if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
            raise ClodsError("not a SimVP checkpoint of this version", where=str(path), hint=hint)
        if payload["digest"] != digest:
            raise ClodsError("SimVP checkpoint was trained with another config or other videos", where=str(path), hint=hint)
        model.load_state_dict(payload["model"])
        opt.load_state_dict(payload["optimizer"])
        sched.load_state_dict(payload["scheduler"])
        return int(payload["step"]), list(payload["losses"])

    @torch.no_grad()
    def predict(self, context: np.ndarray, num_frames: int, cameras: Sequence[Any] = ()) -> np.ndarray:
        """(N,num_frames,H,W,3): from each view's last `context_frames` frames, blocks of predictions fed back in."""
        if self.model is None or self.size is None:
            raise ClodsError("predict called before fit", where="simvp")
        c = self.cfg
        ctx = check_video(context, where="simvp.predict: context", ndim=5)
        if ctx.shape[2:4] != self.size:
            raise ClodsError(f"context frames are {ctx.shape[2]}x{ctx.shape[3]} px, the model was trained on {self.size[0]}x{self.size[1]}", where="simvp.predict")
        if ctx.shape[1] < c.context_frames:
            raise ClodsError(f"needs {c.context_frames} context frames, got {ctx.shape[1]}", where="simvp.predict", hint="lower video_config.simvp.context_frames")
        x = torch.from_numpy(np.ascontiguousarray(ctx[:, -c.context_frames :].transpose(0, 1, 4, 2, 3)))
        out = []
        with torch_threads(c.num_threads or None):
            while sum(o.shape[1] for o in out) < num_frames:
                x = self.model(x).clamp(0.0, 1.0)
                out.append(x)
        pred = torch.cat(out, dim=1)[:, :num_frames] if out else x[:, :0]
        return pred.permute(0, 1, 3, 4, 2).numpy().astype(np.float32)
