"""Plugin descriptors: one small frozen dataclass per plugin, holding name, config class and description."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Literal, Mapping

if TYPE_CHECKING:
    from clods_bench.benchmark.core.config import RunConfig
    from clods_bench.datasets.scenes import SceneSpec


@dataclass(frozen=True)
class EmptyConfig:
    """Configuration of a plugin that has no options."""


@dataclass(frozen=True)
class BuildContext:
    """What a plugin factory may look at when it builds its object."""

    scene: "SceneSpec"
    seed: int
    work_dir: Path
    progress: bool = True


@dataclass(frozen=True)
class PluginSpec:
    """A simulator or renderer plugin: `build(config, context)` returns the object.

    `config_cls` is a dataclass; the run's `sim_config` / `renderer_config` mapping is
    loaded into it (unknown keys are an error), so every option is typed and documented. It may
    declare its own rules as `validate(where)` (or `validate()`), raising ClodsError naming the
    field; `make_config` runs them, and requires every number to be finite, before any work.
    """

    name: str
    description: str
    build: Callable[[Any, BuildContext], Any]
    config_cls: type = EmptyConfig
    learned: bool = False
    devices: tuple[str, ...] | None = None
    """Device kinds the plugin runs on ('cpu', 'cuda'); None: 'cpu', and 'cuda' too when its config has a `device`
    option. The run's `device` (`--device`) reaches the plugin only for a kind listed here: one that lists 'cpu'
    alone stays on the CPU (the run names it), and its `device` option set to another kind is an error."""
    label: str | None = None
    """The name its table rows print (a published model's name, e.g. 'MGN'); None: the plugin name. Tables, docs and
    claims all take it from here (`row_label`), so they cannot disagree."""
    variant: str | None = None
    """How it differs from the published model it is named after, in a few words (e.g. 'MGN cloth frame'); every row
    then prints it after the name: 'BSMS (MGN cloth frame)'. None: it is that model (same architecture, loss and
    training recipe, shown by a same-weights comparison)."""

    def row_label(self, first_half: bool = False) -> str:
        """The table row label: the label (or name), '*' for the first-half training subset, then '(variant)'."""
        base = (self.label or self.name) + ("*" if first_half else "")
        return f"{base} ({self.variant})" if self.variant else base

    def make_config(self, values: Mapping[str, Any], where: str) -> Any:
        """Load a mapping into this plugin's config dataclass, failing loudly on unknown keys, and check its values:
        the class's own `validate(where)` (or `validate()`) when it has one, then every number finite. A run resolves
        its plugins' configs before any data is generated, so a bad value stops it before any work."""
        from clods_bench.typed_config import check_config, dataclass_from_dict

        config = dataclass_from_dict(self.config_cls, dict(values), where)
        check_config(config, where)
        return config


@dataclass(frozen=True)
class TaskResult:
    """What one seed of a task returns: flat metrics, timings (seconds) and optional arrays."""

    metrics: dict[str, float]
    timings: dict[str, float]
    curves: dict[str, list[float]] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TaskContext:
    """Everything a task's `run` gets for one seed."""

    config: "RunConfig"
    seed: int
    work_dir: Path
    registry: Any  # clods_bench.benchmark.core.registry.Registry (Any to avoid an import cycle)


@dataclass(frozen=True)
class TableLayout:
    """How a task's run records become its table, in `clods-bench tables`, `clods-bench report` and `reproduce`.

    `frame(records)` gets the records of one table (each a run's `record.json` as a dict, its `label` the row's) and
    returns (display, numeric, notes): a pandas DataFrame shown as markdown, LaTeX and HTML (its index: the row
    labels), one written as CSV, and footnotes (strings). `clods_bench.api.metric_frame` makes one column per metric.
    """

    frame: Callable[[list[dict[str, Any]]], tuple[Any, Any, list[str]]]
    caption: Callable[[str, str, list[dict[str, Any]], list[str]], str] | None = None
    """(scene, preset, records, notes) -> the caption `clods-bench tables` writes above the table (scene is '' when
    one table holds several scenes); None: the task's name, scene, preset and seeds, then the notes."""
    per: Literal["scene", "preset"] = "scene"
    """'scene': one table per (scene, preset), rows by label; 'preset': one per preset, rows by (label, scene)
    (the stability table, whose rows are simulators on several scenes)."""


@dataclass(frozen=True)
class TaskSpec:
    """A benchmark task: `run(context) -> TaskResult` for one seed; `needs` names required plugin kinds."""

    name: str
    description: str
    run: Callable[[TaskContext], TaskResult]
    needs: tuple[Literal["sim", "renderer"], ...] = ()
    datasets: Callable[[Any, Any], list[Any]] | None = None
    """(RunConfig, Registry) -> the DataConfigs a run reads besides `config.data` (CDG's `eval_data`): the runner
    generates them before any seed runs; a bad option raises ClodsError naming it. None: only `config.data`."""
    table: TableLayout | None = None
    """The layout of the task's table (`TableLayout`); None: the task has no table, and `clods-bench tables`,
    `report` or `reproduce` asked for one stop with an error naming this field."""
    row_label: Callable[[Any], str | None] | None = None
    """(RunConfig) -> the row label of a run given no `label`, or None for the default: the plugin names joined by
    '+', with '*' for the first-half training subset (CDG labels its CloDS rows 'CloDS**', 'CloDS*', 'CloDS')."""
    device_options: Callable[[Any], Mapping[str, type]] | None = None
    """(RunConfig) -> the task's own option sections that the run's `device` reaches: dotted paths below
    `task_config` (e.g. 'clods.stage0') mapped to their config dataclass, which gets `device` and a 'gsplat' `backend`
    where it has them, as a plugin's config does. None: the task's options take no device."""


def spec_fields(cls: type) -> list[dataclasses.Field]:
    """The dataclass fields of a config class (for `clods-bench list --verbose`)."""
    return list(dataclasses.fields(cls)) if dataclasses.is_dataclass(cls) else []
