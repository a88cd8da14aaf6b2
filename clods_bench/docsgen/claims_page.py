"""Markdown of the claims: the site's page "The paper's claims here" and the README's summary of it."""

from __future__ import annotations

from markdown.extensions.toc import slugify

from clods_bench.docsgen.claims import FAILS, FIXTURE, HOLDS, NOISE, NOT_RUN, Claim
from clods_bench.errors import ClodsError

BADGE = {HOLDS: "holds", FAILS: "**does not hold**", NOISE: "within noise", NOT_RUN: "not run"}


def anchor(claim: Claim) -> str:
    """The anchor of a claim's section on the page."""
    return slugify(claim.title, "-")


def summary_table(claims: list[Claim], page: str | None = "") -> list[str]:
    """One row per claim: title (linked to its section of `page`; None: no link), the paper's place, the verdict per size.

    Sizes of the plan's tables get a column each; other measurements (a GPU's) share the last column."""
    evidence = list(dict.fromkeys(o.size for c in claims for o in c.outcomes if o.kind not in ("measurement", FIXTURE)))
    fixtures = list(dict.fromkeys(o.size for c in claims for o in c.outcomes if o.kind == FIXTURE))
    head = [*evidence, "other measurements", *(f"{s} ({FIXTURE}, not evidence)" for s in fixtures)]
    lines = [f"| claim | in the paper | {' | '.join(head)} |", f"| --- | --- |{' --- |' * len(head)}"]
    for c in claims:
        by_size = {o.size: o for o in c.outcomes}

        def cell(o) -> str:  # noqa: ANN001
            return BADGE[o.status] + ("" if o.counted else " (not counted)")

        other = "; ".join(f"{o.size}: {cell(o)}" for o in c.outcomes if o.kind == "measurement") or "-"
        cells = [cell(by_size[s]) if s in by_size else "-" for s in evidence] + [other]
        cells += [cell(by_size[s]) if s in by_size else "-" for s in fixtures]
        title = c.title if page is None else f"[{c.title}]({page}#{anchor(c)})"
        lines.append(f"| {title} | {c.where} | {' | '.join(cells)} |")
    return lines


def counts(claims: list[Claim]) -> dict[str, dict[str, int]]:
    """Per size label, evidence first and a regression fixture last: how many claims hold, hold only within noise, do
    not hold, did not run (claims the paper scores on another quantity are not counted)."""
    out: dict[str, dict[str, int]] = {}
    kinds: dict[str, str] = {}
    for c in claims:
        for o in c.outcomes:
            kinds[o.size] = o.kind
            tally = out.setdefault(o.size, {HOLDS: 0, NOISE: 0, FAILS: 0, NOT_RUN: 0})
            if o.counted:
                tally[o.status] += 1
    return dict(sorted(out.items(), key=lambda item: kinds[item[0]] == FIXTURE))


def counts_table(claims: list[Claim]) -> list[str]:
    """How many claims hold, hold within noise, do not hold and did not run, per size."""
    lines = ["| size | holds | within noise | does not hold | not run |", "| --- | --- | --- | --- | --- |"]
    kinds = {o.size: o.kind for c in claims for o in c.outcomes}
    for size, n in counts(claims).items():
        name = f"{size} ({FIXTURE}, not evidence)" if kinds[size] == FIXTURE else size
        lines.append(f"| {name} | {n[HOLDS]} | {n[NOISE]} | {n[FAILS]} | {n[NOT_RUN]} |")
    return lines


def check_anchors(claims: list[Claim]) -> None:
    """Two claims whose titles give the same anchor would link to one section: refuse them."""
    seen: dict[str, str] = {}
    for c in claims:
        if anchor(c) in seen:
            raise ClodsError(f"claims '{seen[anchor(c)]}' and '{c.id}' have titles with the same anchor '{anchor(c)}'", where="docs/claims.yaml")
        seen[anchor(c)] = c.id


def claims_body(claims: list[Claim]) -> str:
    """The page below its introduction: counts, the verdict table and each claim's section."""
    check_anchors(claims)
    lines = ["## Summary", "", *counts_table(claims), "", *summary_table(claims), "", "## The claims one by one", ""]
    for c in claims:
        lines += [f"### {c.title}", "", f"**The paper** ({c.where}): {c.claim} {c.paper}", "", f"**Rule**: {c.rule_text.rstrip('.')}.", ""]
        lines += ["| size | seeds | ours | verdict |", "| --- | --- | --- | --- |"]
        for o in c.outcomes:
            seeds = "-" if o.seeds is None else str(o.seeds)
            files = ", ".join(f"`{f.name}`" for f in o.files)
            ours = o.ours + (f"<br>from {files}" if files else "") + (f"<br>{o.noise}" if o.noise else "")
            counted = "" if o.counted else " (not counted: the paper scores another quantity)"
            lines.append(f"| {o.size} ({o.kind}) | {seeds} | {ours} | {BADGE[o.status]}{counted} |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"

