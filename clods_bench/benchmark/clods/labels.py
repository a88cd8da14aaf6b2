"""Default table labels of the CloDS rows of the paper's Table 2 (the CDG task declares them as its row labels)."""

from __future__ import annotations

from typing import Any

DEFAULT_PLUGINS = ("mgn", "smgs")  # the paper's CloDS: MGN simulator, SMGS renderer


def clods_label(cfg: Any) -> str:
    """'CloDS**' (all training videos), 'CloDS*' (first half) or 'CloDS' (MGN* fine-tuned on the second half's videos);
    other plugins than MGN + SMGS are named in brackets, e.g. 'CloDS**[bsms+games]'."""
    variant = dict(cfg.task_config.get("clods", {}) or {}).get("variant", "scratch")
    stars = "" if variant == "finetune" else ("*" if cfg.train_subset == "first_half" else "**")
    plugins = (cfg.sim, cfg.renderer)
    return "CloDS" + stars + ("" if plugins == DEFAULT_PLUGINS else f"[{'+'.join(str(p) for p in plugins)}]")
