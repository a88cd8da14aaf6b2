"""Results tables at a glance: the Avg. columns shown, every column behind a toggle, numbers aligned and unbroken."""

from __future__ import annotations

from clods_bench.docsgen.glance import NBSP, glance, glance_columns, numeric_columns, split_row

TABLE = [
    "| Method | G / a / d_avg | G / a / Avg. | H / b / Avg. | Time / fit s |",
    "|:--|:--|:--|:--|--:|",
    "| A | 0.1 ± 0.2 | 0.3 ± 0.4 | 0.5 ± 0.6 | 7 |",
    "| B \\| C | 1.0 ± 0.0 | 2.0 ± 0.0 | 3.0 ± 0.0 | 8 |",
]


def test_rows_split_on_unescaped_bars() -> None:
    assert split_row("| B \\| C | 1 |") == ["B \\| C", "1"]


def test_the_avg_columns_and_the_groups_without_one_are_shown_at_a_glance() -> None:
    assert glance_columns(split_row(TABLE[0])) == [0, 2, 3, 4]
    assert glance_columns(["Model", "Quality / PSNR", "Time / fit s"]) is None  # no Avg. column: shown whole
    assert glance_columns(["M", "G / Avg."]) is None  # nothing to hide


def test_a_table_becomes_its_glance_then_the_whole_table_in_a_details_block() -> None:
    out = glance(["*caption*", "", *TABLE, "", "footnote"])
    text = "\n".join(out)
    pm = f"{NBSP}±{NBSP}"
    assert out[:4] == ["*caption*", "", '<div class="clods-table" markdown>', ""]
    assert out[4:9] == [
        "| Method | G / a / Avg. | H / b / Avg. | Time / fit s |",
        "| :--- | ---: | ---: | ---: |",
        f"| A | 0.3{pm}0.4 | 0.5{pm}0.6 | 7 |",
        f"| B \\| C | 2.0{pm}0.0 | 3.0{pm}0.0 | 8 |",
        "",
    ]
    assert '<details class="clods-table-all" markdown>\n<summary>All 4 columns</summary>' in text
    assert f"| A | 0.1{pm}0.2 | 0.3{pm}0.4 | 0.5{pm}0.6 | 7 |" in text  # the whole row, behind the toggle
    assert text.endswith("</details>\n\n</div>\n\nfootnote")
    assert " ± " not in text


def test_a_table_without_avg_columns_is_shown_whole_and_aligned() -> None:
    out = glance(["| Model | PSNR | fit s |", "|:--|:--|--:|", "| A | 20.1 ± 0.3 | 5 |"])
    assert out == ['<div class="clods-table" markdown>', "", "| Model | PSNR | fit s |", "| :--- | ---: | ---: |",
                   f"| A | 20.1{NBSP}±{NBSP}0.3 | 5 |", "", "</div>"]  # fmt: skip


def test_number_columns_are_right_aligned_and_text_columns_left() -> None:
    rows = [["A", "flag", "0.23 ± 0.01", "frame 10 (4/4 rollouts): strain 0.5", "12.5", "unavailable¹"],
            ["B", "storm", "diverged", "stable", "1,000", "0.31"]]  # fmt: skip
    assert numeric_columns(rows) == {2, 4, 5}
    out = glance(["| M | Scene | RMSE | Divergence | ms | LPIPS |", "|:--|:--|:--|:--|--:|:--|", *(f"| {' | '.join(r)} |" for r in rows)])
    assert out[3] == "| :--- | :--- | ---: | :--- | ---: | ---: |"
