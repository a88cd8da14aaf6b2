"""The migrating guide's scene section, run as written: each 'before' block (the deprecated form) and its 'now' block
make the same mesh and the same dataset fingerprint, and only 'before' warns."""

from __future__ import annotations

import re
import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest

from clods_bench.api import PluginAPIDeprecationWarning, SceneSpec, SolverParams
from clods_bench.datasets.generate import scene_fingerprint
from clods_bench.datasets.meshes import make_flag_mesh

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "plugins" / "migrating.md"


def _blocks() -> list[str]:
    """The Python blocks of the section on `kind` and `build_mesh`, in order."""
    text = GUIDE.read_text()
    section = text.split("{ #scenes-kind-and-build_mesh }")[1]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def _run(code: str) -> tuple[list[SceneSpec], list[str]]:
    """Exec one block (each bare `SceneSpec(...)`/`NarrowFlag(...)` line collected); the scenes and the warnings."""
    module = types.ModuleType("migrating_guide_block")  # dataclasses look their module up in sys.modules
    module.__dict__.update(PARAMS=SolverParams(air_drag=0.02), make_flag_mesh=make_flag_mesh, SceneSpec=SceneSpec, _made=[])
    lines = [f"_made.append({line})" if re.match(r"^(SceneSpec|NarrowFlag)\(", line) else line for line in code.splitlines()]
    sys.modules[module.__name__] = module
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            exec("\n".join(lines), module.__dict__)  # noqa: S102 - the guide's own code
    finally:
        del sys.modules[module.__name__]
    return module._made, [str(w.message) for w in caught if issubclass(w.category, PluginAPIDeprecationWarning)]


def _same(old: SceneSpec, new: SceneSpec) -> None:
    a, b = old.build_mesh(), new.build_mesh()
    for field in ("cells", "mesh_pos", "node_type", "rest_pos"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert scene_fingerprint(old) == scene_fingerprint(new)  # the same dataset: generated data is reused


def test_the_guides_blocks_cover_both_cases() -> None:
    assert len(_blocks()) == 3  # a built-in kind (before and now), an override before, the same now


def test_builtin_kind_before_and_now() -> None:
    both, warned = _run(_blocks()[0])
    assert len(both) == 2 and len(warned) == 1 and "cloth=FlagCloth(size=(1.0, 0.4), default_resolution=(8, 4))" in warned[0]
    _same(*both)


def test_build_mesh_override_before_and_now() -> None:
    (old,), warned_old = _run(_blocks()[1])
    (new,), warned_new = _run(_blocks()[2])
    assert len(warned_old) == 2 and warned_new == []
    assert old.name == new.name == "narrow"
    _same(old, new)


@pytest.mark.parametrize("block", [0, 2])
def test_today_form_lines_run_without_warnings(block: int) -> None:
    code = _blocks()[block]
    now = code.split("# now", 1)[-1]
    _, warned = _run(now)
    assert warned == []
