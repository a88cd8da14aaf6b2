"""The shell commands of the docs' code blocks, and how each is checked without running the long ones.

A `clods-bench` command is parsed by the real argument parser; on the README, the getting-started page and the
plugin guide its configuration is also built and its plugins resolved (a registry of the built-ins and of the
guide's example plugins), which is everything a run does before it computes; the cheap ones (`list`, `--help`,
`reproduce --dry-run`) run whole. Other programs are checked for what can go stale: files and extras they name.
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from clods_bench.errors import ClodsError
from tests.docs.pages import ROOT, code_blocks

SHELL_LANGS = ("bash", "sh", "shell", "console")
CLODS = ("clods-bench", ".venv/bin/clods-bench")
PYTHON = ("python", "python3", ".venv/bin/python")
PIP = ("pip", ".venv/bin/pip")
EXTERNAL = ("mkdocs", "tox", "ray", "git", "nvidia-smi", "cd", "export", "for", "do", "done", "cp")
"""Programs outside the project: only their presence in a command is accepted."""


@dataclass(frozen=True)
class Command:
    """One simple command of a page: where it is and its words (environment assignments left out)."""

    page: str
    line: int
    words: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.page}:{self.line}: {' '.join(self.words)}"


def commands(path: Path) -> list[Command]:
    """The simple commands of every shell code block of a page, continuation lines joined, split at && ; |."""
    out = []
    page = str(path.relative_to(ROOT))
    for block in code_blocks(path.read_text()):
        if block.lang not in SHELL_LANGS:
            continue
        joined, start = "", None
        for offset, line in enumerate(block.lines):
            start = block.line + offset if start is None else start
            if line.rstrip().endswith("\\"):
                joined += line.rstrip()[:-1] + " "
                continue
            words = shlex.split(joined + line, comments=True)
            joined, first = "", start
            start = None
            for part in _split(words):
                while part and "=" in part[0] and not part[0].startswith(("-", ".", "/")):
                    part = part[1:]  # VAR=value prefixes
                if part:
                    out.append(Command(page, first, tuple(part)))
    return out


def _split(words: list[str]) -> list[list[str]]:
    parts, cur = [], []
    for w in words:
        if w in ("&&", "||", ";", "|"):
            parts.append(cur)
            cur = []
        else:
            cur.append(w)
    return [*parts, cur]


def extras() -> set[str]:
    """The optional-dependency groups of the project (read from pyproject.toml's own section; no TOML parser is
    needed on Python 3.10)."""
    text = (ROOT / "pyproject.toml").read_text()
    section = text.split("[project.optional-dependencies]", 1)[1].split("\n[", 1)[0]
    return set(re.findall(r"^([A-Za-z0-9_-]+)\s*=", section, re.M))


def check_other(cmd: Command) -> str | None:
    """Problems of a command that is not `clods-bench`, or None."""
    prog, args = cmd.words[0], list(cmd.words[1:])
    if prog in PIP:
        for a in args:
            if a.startswith((".", "/")) and not a.startswith("./.") and "[" not in a and not (ROOT / a).exists():
                return f"pip installs {a}, which does not exist"
            if a.startswith(".[") and not set(a[2:-1].split(",")) <= extras():
                return f"no extra {a[2:-1]} in pyproject.toml (extras: {', '.join(sorted(extras()))})"
        return None
    if prog in PYTHON:
        if args[:1] == ["-m"] or args[:1] == ["-c"]:
            module = args[1] if len(args) > 1 else ""
            if module == "pytest":
                missing = [a for a in args[2:] if a.startswith("tests") and not (ROOT / a.split("::")[0]).exists()]
                return f"no test path {missing}" if missing else None
            return None if module in ("venv", "clods_bench.docsgen") or args[0] == "-c" else f"unexpected module {module}"
        script = ROOT / args[0]
        return None if script.is_file() else f"no script {args[0]}"
    if prog in ("bash", "source"):
        target = args[0] if args else ""
        return None if target == ".venv/bin/activate" or (ROOT / target).is_file() else f"no script {target}"
    if prog in EXTERNAL:
        return None
    return f"unknown program '{prog}' (add it to tests/docs/commands.py if it belongs in the docs)"


def parse(words: tuple[str, ...]) -> Any:
    """The argparse namespace of a `clods-bench` command; argparse's complaint as a ClodsError."""
    from clods_bench.cli import build_parser

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            return build_parser().parse_args(list(words[1:]))
    except SystemExit as exc:
        if exc.code == 0:  # --help
            return None
        raise ClodsError(err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else "argparse refused it") from None


def resolve(args: Any, registry: Any) -> None:
    """Everything a command does before it computes: its config built, its plugins and plan resolved."""
    from clods_bench.benchmark.core.config import load_config
    from clods_bench.benchmark.core.resolve import resolve_plugins

    def config(**fields: Any) -> Any:
        overrides = [*( [f"data.scene={args.scene}"] if getattr(args, "scene", None) else []), *args.overrides]
        return load_config(args.preset, args.config, overrides, **fields)

    if args.command == "run":
        cfg = config(task=args.task, sim=args.sim, renderer=args.renderer, predictor=args.predictor, label=args.label,
                     train_subset=args.train_subset, seeds=args.seeds)  # fmt: skip
        resolve_plugins(cfg, registry)
    elif args.command == "data" and args.data_command in ("generate", "export"):
        registry.get("scene", config().data.scene)
    elif args.command == "reproduce":
        from clods_bench.benchmark.reproduction.reproduce import load_plan

        plan = load_plan(args.plan)
        unknown = sorted(set(args.only) - {t.id for t in plan.tables})
        if unknown:
            raise ClodsError(f"--only names tables the plan does not have: {unknown}")


RUN_WHOLE = (("list",), ("numerics",))


def run_whole(cmd: Command) -> bool:
    """Whether a command is cheap enough to run in the test: list, numerics, reproduce --dry-run."""
    words = cmd.words[1:]
    return words in RUN_WHOLE or (words[:1] == ("reproduce",) and "--dry-run" in words)
