"""The parts of a run config that are not a plugin's options, checked before any work (`resolve_plugins` calls
`check_run`): the seeds, the plugin names that hold options, the task options' numbers (finite; their ranges are
the task's to check), and every dataset the run reads (its values and the memory its largest arrays need)."""

from __future__ import annotations

from typing import Any, Sequence

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.registry import Registry
from clods_bench.datasets.data_checks import MAX_SEED, check_data, check_memory
from clods_bench.errors import ClodsError
from clods_bench.typed_config import check_finite_fields

OPTION_SECTIONS = (("sim_config", "simulator"), ("renderer_config", "renderer"), ("video_config", "video_predictor"))
"""The RunConfig sections of options per plugin name, with the registry kind that names their keys."""


def check_run(cfg: RunConfig, registry: Registry, datasets: Sequence[tuple[Any, str]]) -> None:
    """Raise ClodsError naming the first bad value of `cfg` outside its plugins' options: seeds, option sections,
    then each of `datasets` ((DataConfig, where) pairs: the run's own data and the task's extra datasets)."""
    check_seeds(cfg.seeds)
    check_option_sections(cfg, registry)
    check_finite_fields(cfg.task_config, "task_config")  # the tasks check their ranges when they start; NaN never works
    for data, where in datasets:
        check_data(data, where)
    for data, where in datasets:  # memory last: a wrong value is named before a size is blamed
        check_memory(data, registry.get("scene", data.scene), where)


def check_seeds(seeds: Any, where: str = "seeds") -> None:
    """Raise ClodsError unless `seeds` is a non-empty list of distinct integers in [0, 2^32 - 1]."""
    if not isinstance(seeds, (list, tuple)) or not seeds:
        raise ClodsError(f"must be a non-empty list of seeds, got {seeds!r}", where=where, hint="e.g. --seeds 0 1")
    for i, seed in enumerate(seeds):
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            raise ClodsError(f"must be an integer in [0, {MAX_SEED}], got {seed!r}", where=f"{where}[{i}]")
    repeated = sorted({s for s in seeds if list(seeds).count(s) > 1})
    if repeated:
        raise ClodsError(f"lists seed(s) {repeated} more than once", where=where)


def check_option_sections(cfg: RunConfig, registry: Registry) -> None:
    """Raise ClodsError for options given to a plugin that is not installed (a misspelt `--set sim_config.mgm.x=1`
    would otherwise be ignored without a word), naming the closest installed name."""
    for section, kind in OPTION_SECTIONS:
        for name in getattr(cfg, section, None) or {}:
            try:
                registry.get(kind, str(name))
            except ClodsError as exc:
                raise ClodsError(exc.what, where=f"{section}.{name}", hint=exc.hint) from None
