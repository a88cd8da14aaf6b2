"""The package's layering (docs/development.md "Layers"), read from the source with `ast`.

Bottom to top: the root utilities and `numerics` <- `datasets` <- `splatting` <- the benchmark core (`scoring` <-
`core` <- `running` <- `outputs` <- `reproduction`) <- the CloDS layer (`benchmark/clods/`) and the plugins <- the
tasks and the speed benchmarks <- the CLI <- `api.py` and `docsgen`. A module imports its own package and the
layers below it, never a layer above nor a sibling of its own layer. Every import counts: module level, inside
functions and under `if TYPE_CHECKING:`. Besides: only `tasks.builtin` (and the CLI) import a task module, only the
plugins import a plugin module (the built-in ones register through entry points like any other), nothing imports
`clods_bench.api`, module-level imports form no cycle, and no module is longer than MAX_LINES.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "clods_bench"
TASKS = "clods_bench.benchmark.tasks"
PLUGINS = "clods_bench.plugins"
MAX_LINES = 450

LAYERS: tuple[tuple[str, ...], ...] = (
    # the root utilities: the package itself, errors, atomic files, the API version; devices, typed config loading,
    # exact numerics and the integrity seals on them
    ("clods_bench", "clods_bench.benchmark", "clods_bench.errors", "clods_bench.atomic", "clods_bench.api_version"),
    ("clods_bench.devices", "clods_bench.typed_config", "clods_bench.numerics", "clods_bench.integrity"),
    ("clods_bench.datasets",),
    ("clods_bench.splatting",),
    # the benchmark core, in five steps
    ("clods_bench.benchmark.scoring",),
    ("clods_bench.benchmark.core",),
    ("clods_bench.benchmark.running",),
    ("clods_bench.benchmark.outputs",),
    ("clods_bench.benchmark.reproduction",),
    ("clods_bench.benchmark.clods", PLUGINS),
    (TASKS, "clods_bench.benchmark.speed"),
    ("clods_bench.cli",),
    ("clods_bench.api", "clods_bench.docsgen"),
)  # fmt: skip
"""Each entry a layer, bottom first; the packages of one layer are siblings (neither imports the other)."""
EXACT = {"clods_bench", "clods_bench.benchmark"}
"""Package entries that hold only their own `__init__` (their subpackages have entries of their own)."""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in PKG.rglob("*.py")}


def _imports(path: Path, top_level_only: bool = False) -> set[str]:
    """Every clods_bench module `path` imports. `from a.b import c` counts a.b.c when that is a module, and a.b too
    unless every name is a module (importing a submodule only needs the package started, which is no cycle)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    for node in _top_level(tree) if top_level_only else ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("clods_bench")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("clods_bench") and node.level == 0:
            submodules = {f"{node.module}.{a.name}" for a in node.names} & MODULES.keys()
            found |= submodules
            if len(submodules) < len(node.names):
                found.add(node.module)
    return found & MODULES.keys()


def _top_level(tree: ast.Module) -> list[ast.AST]:
    """The statements that run on import: the module body, with the bodies of its `try` and `if` blocks, except
    `if TYPE_CHECKING:` (annotations only)."""
    out, todo = [], list(tree.body)
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If):
            if not (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"):
                todo.extend([*node.body, *node.orelse])
            continue
        if isinstance(node, ast.Try):
            todo.extend([*node.body, *node.orelse, *node.finalbody, *(s for h in node.handlers for s in h.body)])
            continue
        out.append(node)
    return out


def _entry(name: str) -> tuple[int, str]:
    """(layer index, package entry) of a module: its longest matching entry."""
    best: tuple[int, str] | None = None
    for index, layer in enumerate(LAYERS):
        for prefix in layer:
            hit = name == prefix or (prefix not in EXACT and name.startswith(prefix + "."))
            if hit and (best is None or len(prefix) > len(best[1])):
                best = (index, prefix)
    assert best is not None, f"{name} is in no layer: add its package to LAYERS"
    return best


def test_the_scan_sees_the_package() -> None:
    assert {"clods_bench.benchmark.tasks.cdg", "clods_bench.benchmark.core.builders", "clods_bench.datasets.store"} <= MODULES.keys()
    assert "clods_bench.benchmark.core.builders" in _imports(MODULES["clods_bench.benchmark.tasks.cdg"])
    assert _entry("clods_bench.benchmark.clods.stage1") == (9, "clods_bench.benchmark.clods")


def test_every_module_has_a_layer() -> None:
    for name in MODULES:
        _entry(name)


def test_imports_go_down_the_layers() -> None:
    """A module imports its own package and lower layers only: 0 upward imports, 0 imports of a sibling package."""
    bad = []
    for name, path in sorted(MODULES.items()):
        layer, entry = _entry(name)
        for target in sorted(_imports(path)):
            their_layer, their_entry = _entry(target)
            if their_entry != entry and their_layer >= layer:
                bad.append(f"{name} -> {target}")
    assert not bad, "imports up (or sideways) the layers:\n  " + "\n  ".join(bad)


def test_no_module_imports_a_task_module() -> None:
    bad = {
        name: sorted(m for m in _imports(path) if m.startswith(f"{TASKS}.") and m != name)
        for name, path in MODULES.items()
        if name not in (TASKS, f"{TASKS}.builtin") and not name.startswith("clods_bench.cli")
    }
    assert not {k: v for k, v in bad.items() if v}, "shared code belongs in benchmark/core/builders.py or below"


def test_only_plugins_import_plugin_modules() -> None:
    """Built-in plugins are reached through the registry, like third-party ones."""
    bad = {
        name: sorted(m for m in _imports(path) if m.startswith(PLUGINS + "."))
        for name, path in MODULES.items()
        if not name.startswith(PLUGINS)
    }
    assert not {k: v for k, v in bad.items() if v}


def test_nothing_imports_the_api_facade() -> None:
    assert not [name for name, path in MODULES.items() if "clods_bench.api" in _imports(path)]


def test_module_level_imports_form_no_cycle() -> None:
    graph = {name: _imports(path, top_level_only=True) - {name} for name, path in MODULES.items()}
    state: dict[str, int] = {}  # 1: on the stack, 2: done

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*stack[stack.index(nxt):], node, nxt]) if nxt in stack else f"{node} -> {nxt}")
            if nxt not in state:
                visit(nxt, [*stack, node])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])


def test_modules_are_short() -> None:
    long = {name: n for name, path in MODULES.items() if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines (split them by job): {long}"
