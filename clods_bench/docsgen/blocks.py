"""Generated blocks inside hand-written pages: the presets table and the README's headline results.

A block sits between `<!-- generated:NAME -->` and `<!-- end generated:NAME -->`; `fill` rewrites what is
between them, so the prose around a block is edited by hand and the numbers inside it never are.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

from clods_bench.docsgen.claims import evaluate_claims
from clods_bench.docsgen.claims_page import claims_body, counts_table, summary_table
from clods_bench.benchmark.outputs.table_sources import CsvTable
from clods_bench.errors import ClodsError

BLOCK = re.compile(r"(<!-- generated:(?P<name>[a-z0-9_-]+)[^>]*-->\n)(?P<body>.*?)(<!-- end generated:(?P=name) -->)", re.S)
CDG_AVG = ("viewed/interp/avg/mean", "viewed/extrap/avg/mean", "unviewed/interp/avg/mean", "unviewed/extrap/avg/mean")
HEADLINE_ROWS = ("Physics", "Frozen", "MGN", "MGN*", ("simulator", "bsms"), ("simulator", "hcmt"), ("simulator", "dhmp"), "CloDS*",
                 "CloDS**", "CloDS")  # fmt: skip
"""Table 2's rows in the README; a (kind, plugin) pair stands for that plugin's own row label (`PluginSpec.row_label`)."""
SMALL_TABLE2 = Path("results/small-partial/2026-12-07-table2-rerun/cdg_flag_small.csv")
"""`small`'s Table 2 on the current data generator and deterministic mode; rows it lacks come from results/small-partial."""


def headline_rows() -> list[str]:
    """HEADLINE_ROWS with every plugin's row label read from its registration."""
    from clods_bench.benchmark.core.registry import default_registry

    registry = default_registry()
    return [row if isinstance(row, str) else registry.get(*row).row_label() for row in HEADLINE_ROWS]


def presets_table(root: Path) -> str:
    """One row per built-in preset, read from the preset files through the config loader."""
    from clods_bench.benchmark.core.config import load_config, preset_description, preset_names
    from clods_bench.benchmark.core.registry import default_registry

    mgn = default_registry().get("simulator", "mgn")  # the learned simulators' training length, as MGN's config reads it

    lines = ["| preset | seeds | mesh nodes | trajectories (train + test) | frames (interpolation) | cameras (held out) | image | learned simulators train | what for |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    order = {"ci": 0, "small": 1, "paper": 2}
    for name in sorted(preset_names(), key=lambda n: (order.get(n, 3), n)):
        cfg = load_config(name)
        d = cfg.data
        nodes = "1579 (FLAGSIMPLE)" if d.resolution == "flagsimple" else str(d.resolution[0] * d.resolution[1])
        steps = mgn.make_config(cfg.sim_config.get("mgn") or {}, where=f"preset {name}: sim_config.mgn").train_steps
        lines.append(f"| `{name}` | {len(cfg.seeds)} | {nodes} | {d.num_train} + {d.num_test} | {d.num_steps} ({d.interp_steps}) | "
                     f"{d.num_cameras} ({d.num_views_test}) | {d.image_size} px | {steps:,} steps | {preset_description(name)} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def _cdg_rows(csv: Path, label: str, aliases: dict[str, str], skip: set[str] = frozenset()) -> tuple[list[str], set[str]]:
    """The headline rows of one Table 2 CSV (those not in `skip`), and which rows it gave."""
    table = CsvTable([csv], aliases=aliases)
    out, given = [], set()
    for row in headline_rows():
        if row in table.rows and row not in skip:
            values = " | ".join(f"{table.value(row, c):.4f}" for c in CDG_AVG)
            out.append(f"| {row} | {label} | {table.seeds([row])} | {values} |")
            given.add(row)
    return out, given


def headline_results(root: Path) -> str:
    """Table 2's Avg. columns of the main rows at `ci` and `small`, read from the committed CSV files."""
    from clods_bench.benchmark.outputs.table_sources import load_yaml

    sizes = load_yaml(root / "docs/claims.yaml")["sizes"]
    small_aliases = (sizes["small"].get("aliases") or {}).get("table2_cdg", {})
    current = root / SMALL_TABLE2
    links = ([f"[`small`]({SMALL_TABLE2.with_suffix('.md').as_posix()})"] if current.is_file() else []) + [
        "[`small`, earlier data](results/small-partial/cdg_flag_small.md)", "[`ci`](results/ci/table2_cdg.md)"]
    lines = ["Table 2 (cloth dynamics grounding), rollout RMSE in metres, Avg. columns; the evidence first, the regression "
             f"fixture last (every row and column: {', '.join(links)}):", "",
             "| method | preset (kind) | seeds | viewed interp. | viewed extrap. | unviewed interp. | unviewed extrap. |",
             "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    given: set[str] = set()
    if current.is_file():
        rows, given = _cdg_rows(current, "`small` (evidence, in part)", {})
        lines += rows
    lines += _cdg_rows(root / "results/small-partial/cdg_flag_small.csv", "`small`, earlier generator (evidence, in part)", small_aliases, given)[0]
    lines += _cdg_rows(root / "results/ci/table2_cdg.csv", "`ci` (regression fixture)", {})[0]
    return "\n".join(lines) + "\n"


def claims_summary(root: Path) -> str:
    """How many claims hold per size, then the per-claim verdicts (titles without links: the claims page's sections
    exist only in the built site)."""
    claims = evaluate_claims(root)
    return "\n".join([*counts_table(claims), "", *summary_table(claims, None)]) + "\n"


def claims_details(root: Path) -> str:
    """The claims page's body: the counts, the verdict table and every claim with its numbers and rule."""
    return claims_body(evaluate_claims(root))


KINDS = ("task", "simulator", "renderer", "video_predictor", "scene")


def plugins_table(root: Path, kinds: tuple[str, ...] = KINDS) -> str:
    """Every installed plugin of `kinds` with its description, as `clods-bench list` prints them (the site is built
    where only the built-ins are installed), so no page describes a plugin in other words than its code."""
    from clods_bench.benchmark.core.registry import default_registry

    reg = default_registry()
    lines = ["| kind | name | description |" if len(kinds) > 1 else "| name | description |",
             "| --- | --- | --- |" if len(kinds) > 1 else "| --- | --- |"]  # fmt: skip
    for kind in kinds:
        for name in reg.names(kind):
            text = " ".join(reg.get(kind, name).description.split()).replace("|", "\\|")
            lines.append(f"| {kind.replace('_', ' ')} | `{name}` | {text} |" if len(kinds) > 1 else f"| `{name}` | {text} |")
    return "\n".join(lines) + "\n"


def task_tables(root: Path) -> str:
    """Every table of the reproduce plan with its task and results page (links relative to docs/tasks/)."""
    from clods_bench.docsgen.results_pages import TASK_PAGES, plan_tables

    lines = ["| table of the plan | task | results |", "| --- | --- | --- |"]
    for t in plan_tables(root):
        task_page = TASK_PAGES.get(t.task, "tasks/index.md").removeprefix("tasks/")
        lines.append(f"| {t.title} | [`{t.task}`]({task_page}) | [`{t.id}`](../results/{t.id}.md) |")
    return "\n".join(lines) + "\n"


def table_costs_block(root: Path) -> str:
    """Seconds per table of the committed `ci` run (links relative to docs/)."""
    from clods_bench.docsgen.results_pages import table_costs

    return table_costs(root, "results/")


GENERATORS: dict[str, Callable[[Path], str]] = {
    "task-tables": task_tables,
    "table-costs": table_costs_block,
    "plugins": plugins_table,
    **{f"plugins-{kind}": (lambda root, kind=kind: plugins_table(root, (kind,))) for kind in KINDS},
    "presets": presets_table,
    "headline-results": headline_results,
    "claims-summary": claims_summary,
    "claims": claims_details,
}


def fill(text: str, root: Path, where: str) -> str:
    """`text` with every generated block rewritten; an unknown block name is an error naming `where`."""

    def one(m: re.Match[str]) -> str:
        name = m.group("name")
        if name not in GENERATORS:
            raise ClodsError(f"unknown generated block '{name}'; known: {', '.join(GENERATORS)}", where=where)
        return m.group(1) + GENERATORS[name](root) + m.group(4)

    return BLOCK.sub(one, text)
