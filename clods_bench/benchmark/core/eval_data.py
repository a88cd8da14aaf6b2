"""Which dataset a CDG run scores its rollouts on (`task_config.cdg.eval_data`), and what the record says about it.

Training always reads `data`; `eval_data` lays overrides over `data` (e.g. `{scene: cylinder}`) to name another
dataset, whose own viewed/unviewed split the rollouts run on: a simulator trained on the flag is scored on the
cylinder's trajectories (shape generalisation, paper Fig. "Generalization capabilities of CloDS" (a)). Empty (the
default) scores on `data` itself, and the run's config, record directory and numbers are what they were before.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.datasets.data_config import DataConfig, data_with_overrides
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

WHERE = "task_config.cdg"


@dataclass(frozen=True)
class CdgConfig:
    """Options of the CDG task (`task_config.cdg.*`)."""

    eval_data: dict[str, Any] = field(default_factory=dict)
    """Overrides of the `data` section naming the dataset the rollouts are scored on (its viewed and unviewed
    trajectories); e.g. {scene: cylinder}. Empty: the training data. `root` is the run's; `path` only when named."""


def cdg_config(cfg: RunConfig) -> CdgConfig:
    """The run's `task_config.cdg` as a checked CdgConfig."""
    opts: CdgConfig = dataclass_from_dict(CdgConfig, dict(cfg.task_config.get("cdg", {}) or {}), where=WHERE, prefix="cdg.")
    return opts


def scored_data(cfg: RunConfig, registry: Any) -> DataConfig:
    """The data config of the dataset the run's rollouts are scored on: `data`, or `data` with `eval_data` laid over it.

    Raises one ClodsError naming `task_config.cdg.eval_data.<field>` for an unknown field, a wrong type or an
    unregistered scene."""
    overrides = cdg_config(cfg).eval_data
    if not overrides:
        return cfg.data
    where = f"{WHERE}.eval_data"
    d = data_with_overrides(cfg.data, overrides, where)
    try:
        registry.get("scene", d.scene)
    except ClodsError as exc:
        raise ClodsError(exc.what, where=f"{where}.scene", hint=exc.hint) from None
    return d


def extra_datasets(cfg: RunConfig, registry: Any) -> list[DataConfig]:
    """Datasets a CDG run reads besides `data` (the runner makes sure they exist before any seed runs)."""
    d = scored_data(cfg, registry)
    return [] if d == cfg.data else [d]
