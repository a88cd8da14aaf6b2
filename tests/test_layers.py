"""The package's layering (README "Layout"): datasets <- benchmark core <- plugins and methods; tasks on top.

Read from the source with `ast`, every import counted (module level and inside functions): no module outside
`benchmark.tasks` imports a task module, task modules do not import each other (only `tasks.builtin` registers
them), `datasets` imports neither the benchmark nor the plugins, and module-level imports form no cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "clods_bench"
TASKS = "clods_bench.benchmark.tasks"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top_level_only: bool = False) -> set[str]:
    """Every clods_bench module `path` imports (`from a.b import c` counts a.b and a.b.c when that is a module)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    for node in tree.body if top_level_only else _walk_run_time(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("clods_bench")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("clods_bench") and node.level == 0:
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in MODULES}
    return found & MODULES.keys()


def _walk_run_time(tree: ast.AST) -> list[ast.AST]:
    """Every node except those under `if TYPE_CHECKING:` (annotations only, nothing imported at run time)."""
    out, todo = [], [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            todo.extend(node.orelse)
            continue
        out.append(node)
        todo.extend(ast.iter_child_nodes(node))
    return out


MODULES = {_module_name(p): p for p in PKG.rglob("*.py")}
DATASETS_UP_IMPORTS = {
    # The built-in scenes register through the plugin hooks like any third-party scene package: the plugin layer.
    "clods_bench.plugins.scenes.builtin": ["clods_bench.benchmark.core.hookspecs"],
    # Known debt: the data config dataclass and its YAML loader live in benchmark/core/config.py.
    "clods_bench.datasets.generate": ["clods_bench.benchmark.core.config"],
}


def test_the_scan_sees_the_package() -> None:
    assert {"clods_bench.benchmark.tasks.cdg", "clods_bench.benchmark.core.builders", "clods_bench.datasets.store"} <= MODULES.keys()
    assert "clods_bench.benchmark.core.builders" in _imports(MODULES["clods_bench.benchmark.tasks.cdg"])


def test_no_module_imports_a_task_module() -> None:
    bad = {
        name: sorted(m for m in _imports(path) if m.startswith(f"{TASKS}.") and m != name)
        for name, path in MODULES.items()
        if name not in (TASKS, f"{TASKS}.builtin")
    }
    assert not {k: v for k, v in bad.items() if v}, "shared code belongs in benchmark/core/builders.py or below"


def test_datasets_import_neither_the_benchmark_nor_the_plugins() -> None:
    bad = {
        name: sorted(m for m in _imports(path) if m.startswith(("clods_bench.benchmark", "clods_bench.plugins")))
        for name, path in MODULES.items()
        if name.startswith("clods_bench.datasets")
    }
    assert {k: v for k, v in bad.items() if v} == DATASETS_UP_IMPORTS


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
