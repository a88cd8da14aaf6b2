"""The training loop shared by the window-trained video predictors (SimVP, TAU, MAU, MMVP).

Protocol (CloDS appendix, 'Dataset details'): the baselines "cannot utilize multi-view videos",
so every view of every training video is a separate single-view sample; windows of
2*`context_frames` consecutive frames give (input, target) pairs. Adam with a one-cycle learning
rate, random windows per step, and a resumable checkpoint (`<name>.pt` in the work directory):
it stores the model, optimizer, scheduler, the window sampler's state and the training seconds spent,
so a resumed run ends with the same weights as an uninterrupted one and a finished checkpoint found
again reports what its training cost. A subclass says how to build its network, its
loss on one batch of windows and how it predicts; everything else is here.
"""

from __future__ import annotations

import abc
import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Generic, Sequence, TypeVar

import numpy as np
import torch
from rich.progress import Progress
from torch import nn

from clods_bench import integrity
from clods_bench.benchmark.core.interfaces import FitContext, check_video
from clods_bench.devices import check_device_name, torch_device
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads
from clods_bench.typed_config import check_count, check_number

CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class WindowTrainConfig:
    """Training options every window-trained predictor has (`video_config.<name>.*`)."""

    context_frames: int = 10
    """Frames in and out of one network pass (10 -> 10 in SimVP, TAU, MAU and MMVP on Moving MNIST)."""
    train_steps: int = 2000
    """Adam steps."""
    batch_size: int = 16
    """Windows per step."""
    learning_rate: float = 1e-3
    """Adam learning rate (one-cycle schedule peaking at this value, as SimVP and TAU train)."""
    checkpoint_every: int = 500
    """Steps between checkpoints (0: only at the end)."""
    num_threads: int = 0
    """torch CPU threads while training/predicting (0: leave torch's setting)."""
    device: str = "cpu"
    """Where the network trains and predicts: 'cpu', 'cuda' or 'cuda:N' (weights initialised on the CPU from the seed,
    windows drawn by the same CPU generator; not part of the checkpoint's identity)."""

    def validate_training(self, name: str, extra_positive: Sequence[str] = ()) -> None:
        """Raise ClodsError naming the field of `video_config.<name>` when a training option cannot work."""
        for field in ("context_frames", "batch_size", *extra_positive):
            if getattr(self, field) < 1:
                raise ClodsError(f"must be >= 1, got {getattr(self, field)}", where=f"video_config.{name}.{field}")
        check_count(self.train_steps, f"video_config.{name}.train_steps")
        check_count(self.checkpoint_every, f"video_config.{name}.checkpoint_every", minimum=0)
        check_number(self.learning_rate, f"video_config.{name}.learning_rate", minimum=0, inclusive=False)
        if self.checkpoint_every < 0 or self.num_threads < 0:
            raise ClodsError("checkpoint_every and num_threads must be >= 0", where=f"video_config.{name}")
        check_device_name(self.device, f"video_config.{name}.device")


C = TypeVar("C", bound=WindowTrainConfig)


def config_digest(name: str, cfg: WindowTrainConfig, videos: Sequence[np.ndarray]) -> str:
    """16 hex digits identifying a predictor, its config and its training videos (a checkpoint's owner)."""
    values = dataclasses.asdict(cfg)
    values.pop("device", None)  # where it trains does not decide the model (and keeps older digests valid)
    h = hashlib.sha256(json.dumps(values, sort_keys=True).encode())
    if name != "simvp":  # SimVP's digest predates the name; keeping it keeps its checkpoints valid
        h.update(name.encode())
    for v in videos:
        h.update(str(v.shape).encode())
        h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()[:16]


def training_windows(
    videos: Sequence[np.ndarray], name: str, context_frames: int, factor: int, layers_option: str
) -> tuple[list[np.ndarray], list[torch.Tensor], list[tuple[int, int]]]:
    """The checked videos, the same as (T,3,H,W) tensors, and the (video, start) of every window of 2*context_frames frames."""
    window = 2 * context_frames
    vids = [check_video(v, where=f"{name}.fit: video {i}") for i, v in enumerate(videos)]
    if not vids:
        raise ClodsError("no training videos", where=f"{name}.fit")
    sizes = {v.shape[1:3] for v in vids}
    if len(sizes) != 1:
        raise ClodsError(f"training videos have different frame sizes {sorted(sizes)}", where=f"{name}.fit")
    h, w = sizes.pop()
    if h % factor or w % factor:
        raise ClodsError(
            f"frames of {h}x{w} px cannot be downsampled {factor}x by the encoder",
            where=f"{name}.fit",
            hint=f"use image sides divisible by {factor} or a smaller video_config.{name}.{layers_option}",
        )
    starts = [(i, s) for i, v in enumerate(vids) for s in range(v.shape[0] - window + 1)]
    if not starts:
        longest = max(v.shape[0] for v in vids)
        raise ClodsError(
            f"{context_frames} context frames need training videos of 2 x {context_frames} = {window} frames; the longest has "
            f"{longest} (the observed frames 0..interp_steps), shorter than one training window",
            where=f"video_config.{name}.context_frames",
            hint=f"set video_config.{name}.context_frames to at most {longest // 2}",
        )
    return vids, [torch.from_numpy(np.ascontiguousarray(v.transpose(0, 3, 1, 2))) for v in vids], starts


class WindowPredictor(abc.ABC, Generic[C]):
    """A video predictor trained from scratch on windows of single-view videos; subclasses supply the network."""

    name: ClassVar[str]
    """Plugin name: the config section (`video_config.<name>`) and the checkpoint file (`<name>.pt`)."""
    label: ClassVar[str]
    """Human name in messages and progress bars."""
    layers_option: ClassVar[str] = "enc_layers"
    """The config field that sets the encoder's downsampling (named in size errors)."""

    def __init__(self, cfg: C, seed: int = 0, progress: bool = True) -> None:
        cfg.validate()  # type: ignore[attr-defined]
        self.cfg, self.seed, self.progress = cfg, seed, progress
        self.model: nn.Module | None = None
        self.size: tuple[int, int] | None = None

    @property
    def checkpoint_file(self) -> str:
        """File name of the resumable checkpoint in the work directory."""
        return f"{self.name}.pt"

    @abc.abstractmethod
    def build_model(self) -> nn.Module:
        """A freshly initialised network (the seed is set before this is called)."""

    @abc.abstractmethod
    def downsample_factor(self) -> int:
        """Image sides must be divisible by this (the encoder's total stride)."""

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        """Training loss on a batch of windows (B,2C,3,H,W); default: MSE of the next C frames predicted from the first C."""
        c = self.cfg.context_frames
        return torch.nn.functional.mse_loss(model(window[:, :c]), window[:, c:])

    def optimizer(self, model: nn.Module) -> tuple[torch.optim.Optimizer, Any]:
        """The optimizer and its per-step learning-rate scheduler; default: Adam, one-cycle peaking at learning_rate."""
        c = self.cfg
        opt = torch.optim.Adam(model.parameters(), lr=c.learning_rate)
        return opt, torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=c.learning_rate, total_steps=c.train_steps)

    def rollout(self, model: nn.Module, context: torch.Tensor, num_frames: int) -> torch.Tensor:
        """(N,num_frames,3,H,W) from the last C frames (N,C,3,H,W); default: blocks of C predictions fed back in."""
        x, out = context, []
        while sum(o.shape[1] for o in out) < num_frames:
            x = model(x).clamp(0.0, 1.0)
            out.append(x)
        return torch.cat(out, dim=1)[:, :num_frames] if out else context[:, :0]

    def fit(self, videos: Sequence[np.ndarray], ctx: FitContext) -> dict[str, float]:
        """Train on windows of 2*context_frames frames of every video; Adam, one-cycle LR; resumable."""
        c = self.cfg
        window = 2 * c.context_frames
        vids, data, starts = training_windows(videos, self.name, c.context_frames, self.downsample_factor(), self.layers_option)
        self.size = (int(data[0].shape[2]), int(data[0].shape[3]))
        dev = torch_device(c.device, f"video_config.{self.name}.device")
        torch.manual_seed(self.seed)
        model = self.build_model().to(dev)
        opt, sched = self.optimizer(model)
        path = Path(ctx.work_dir) / self.checkpoint_file
        digest = config_digest(self.name, c, vids)
        step, losses, rng, before = 0, [], np.random.default_rng(ctx.seed), 0.0
        if path.is_file():
            step, losses, rng, before = self._resume(path, digest, model, opt, sched, ctx.seed)
        t0, spent = time.perf_counter(), before
        show = ctx.progress and self.progress
        with torch_threads(c.num_threads or None), Progress(transient=True, disable=not show) as bar:
            job = bar.add_task(f"{self.name} training", total=c.train_steps, completed=step)
            model.train()
            while step < c.train_steps:
                pick = rng.integers(len(starts), size=c.batch_size)
                batch = torch.stack([data[starts[k][0]][starts[k][1] : starts[k][1] + window] for k in pick]).to(dev)
                loss = self.loss(model, batch, step, rng)
                opt.zero_grad()
                loss.backward()
                opt.step()
                sched.step()
                losses.append(loss.item())
                step += 1
                bar.update(job, completed=step, description=f"{self.name} training (loss {np.mean(losses[-20:]):.2e})")
                if (c.checkpoint_every and step % c.checkpoint_every == 0) or step == c.train_steps:
                    spent = before + time.perf_counter() - t0
                    self._save(path, digest, step, losses, rng, model, opt, sched, spent)
        self.model = model.eval()
        k = max(1, min(20, len(losses) // 10))
        return {
            "train_seconds": spent,  # as of the last checkpoint, with earlier calls' steps (a resumed or cached fit)
            "train_steps": float(c.train_steps),
            "train_windows": float(len(starts)),
            "initial_loss": float(np.mean(losses[:k])),
            "final_loss": float(np.mean(losses[-k:])),
            "parameters": float(sum(p.numel() for p in model.parameters())),
        }

    def _save(
        self, path: Path, digest: str, step: int, losses: list[float], rng: np.random.Generator, model: nn.Module, opt: Any, sched: Any,
        seconds: float = 0.0,
    ) -> None:  # fmt: skip
        payload = {
            "format": CHECKPOINT_FORMAT,
            "digest": digest,
            "step": step,
            "losses": losses,
            "rng": json.dumps(rng.bit_generator.state),
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
            "train_seconds": float(seconds),
        }
        integrity.save_torch(payload, path)  # with its SHA-256, checked by _resume

    def _resume(self, path: Path, digest: str, model: nn.Module, opt: Any, sched: Any, seed: int) -> tuple[int, list[float], np.random.Generator, float]:
        """(step, losses, window sampler, training seconds so far) of the checkpoint at `path`, loaded into the model,
        optimizer and scheduler; a checkpoint of another config or other videos is a ClodsError."""
        hint = "delete it to train from scratch (or use another work directory)"
        integrity.check_zip(path, hint)
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same clear message
            raise ClodsError(f"unreadable {self.label} checkpoint ({type(exc).__name__}: {exc})", where=str(path), hint=hint) from None
        if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
            raise ClodsError(f"not a {self.label} checkpoint of this version", where=str(path), hint=hint)
        if payload["digest"] != digest:
            raise ClodsError(f"{self.label} checkpoint was trained with another config or other videos", where=str(path), hint=hint)
        model.load_state_dict(payload["model"])
        opt.load_state_dict(payload["optimizer"])
        sched.load_state_dict(payload["scheduler"])
        step = int(payload["step"])
        rng = np.random.default_rng(seed + 1000 * step)  # checkpoints written before the sampler state was stored
        if "rng" in payload:
            rng.bit_generator.state = json.loads(payload["rng"])
        return step, list(payload["losses"]), rng, float(payload.get("train_seconds", 0.0))  # 0: written before it was stored

    @torch.no_grad()
    def predict(self, context: np.ndarray, num_frames: int, cameras: Sequence[Any] = ()) -> np.ndarray:
        """(N,num_frames,H,W,3): each view predicted from its own last `context_frames` frames."""
        if self.model is None or self.size is None:
            raise ClodsError("predict called before fit", where=self.name)
        c = self.cfg
        ctx = check_video(context, where=f"{self.name}.predict: context", ndim=5)
        if ctx.shape[2:4] != self.size:
            raise ClodsError(
                f"context frames are {ctx.shape[2]}x{ctx.shape[3]} px, the model was trained on {self.size[0]}x{self.size[1]}", where=f"{self.name}.predict"
            )
        if ctx.shape[1] < c.context_frames:
            raise ClodsError(
                f"needs {c.context_frames} context frames, got {ctx.shape[1]}",
                where=f"video_config.{self.name}.context_frames",
                hint=f"set video_config.{self.name}.context_frames to at most {ctx.shape[1]}",
            )
        x = torch.from_numpy(np.ascontiguousarray(ctx[:, -c.context_frames :].transpose(0, 1, 4, 2, 3)))
        with torch_threads(c.num_threads or None):
            pred = self.rollout(self.model, x.to(next(self.model.parameters()).device), num_frames)
        return pred.permute(0, 1, 3, 4, 2).cpu().numpy().astype(np.float32)
