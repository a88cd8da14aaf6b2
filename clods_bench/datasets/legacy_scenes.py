"""The pre-1.0 scene form, kept working until clods-bench 0.3.0: `SceneSpec(kind=..., size=..., default_resolution=...)`
and subclasses overriding `build_mesh`.

Each use raises a `PluginAPIDeprecationWarning` saying what to write instead. `kind="flag"` / `"cylinder"` map onto
today's `FlagCloth` / `CylinderCloth` (the same data: the fingerprint of the built-in flag written the old way is the
built-in flag's). A `build_mesh` override becomes the mesh of a `LegacySceneCloth`; inside it, `super().build_mesh()`
gives what the old base class gave (the flag of `kind="flag"`, else the tube). Any other `kind` without an override
names nothing to build and is refused with one line naming `cloth=` and the migrating guide's section.
"""

from __future__ import annotations

import contextvars
import dataclasses
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from clods_bench.api_version import DEPRECATED_SINCE, MIGRATING, REMOVED_IN, PluginAPIDeprecationWarning
from clods_bench.datasets.cloths import Cloth, CylinderCloth, FlagCloth, Resolution
from clods_bench.datasets.types import ClothMesh
from clods_bench.errors import ClodsError

GUIDE = f"{MIGRATING}#scenes-kind-and-build_mesh"
"""The migrating guide's section on this form (named in every message)."""

OLD_ORDER = ("name", "description", "kind", "params", "dt", "substeps", "has_obstacles", "has_wind", "has_lighting",
             "has_handles", "size", "default_resolution")  # fmt: skip
"""The pre-1.0 SceneSpec's positional fields up to the last one that moved into the cloth."""
OLD_KEYS = ("kind", "size", "default_resolution")
OLD_DEFAULTS: dict[str, Any] = {"size": (2.0, 1.0), "default_resolution": "flagsimple"}
OVERRIDE = "_legacy_build_mesh"
"""Class attribute holding a subclass's `build_mesh` override, moved aside so that the validating one is used."""

_BUILDING: contextvars.ContextVar[int | None] = contextvars.ContextVar("legacy_scene_building", default=None)


def _tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


@dataclass(frozen=True)
class LegacySceneCloth(Cloth):
    """A cloth whose mesh is a `SceneSpec` subclass's `build_mesh` override (deprecated form): `base` is the old base
    class's cloth (handles fixed, or `base`'s motion), `legacy_kind` the scene's kind."""

    base: Cloth
    legacy_kind: str
    scene: Any = field(default=None, repr=False, compare=False)
    """The scene whose class holds the override (set when the scene is made; not part of the identity)."""

    @property  # type: ignore[override]
    def kind(self) -> str:
        return self.legacy_kind

    @property  # type: ignore[override]
    def default_resolution(self) -> Resolution | None:
        return self.base.default_resolution

    def build(self, resolution: Resolution | None) -> ClothMesh:
        """The override's mesh (its `super().build_mesh()` is `base`'s mesh)."""
        builder: Callable[..., ClothMesh] = getattr(type(self.scene), OVERRIDE)
        token = _BUILDING.set(id(self.scene))
        try:
            return builder(self.scene, resolution)
        finally:
            _BUILDING.reset(token)

    def handle_positions(self, t: float, start: np.ndarray) -> np.ndarray | None:
        return self.base.handle_positions(t, start)

    def identity(self) -> dict[str, Any]:
        """`base`'s identity under the scene's kind: a `kind="flag"` scene keeps the fingerprint it had before 1.0."""
        return {**self.base.identity(), "kind": self.legacy_kind}


def legacy_size(cloth: Cloth) -> Any:
    """The pre-1.0 `SceneSpec.size` (overrides read it): the size of the cloth, or of the one an override stands on."""
    return getattr(cloth.base if isinstance(cloth, LegacySceneCloth) else cloth, "size", None)


def old_base_mesh(scene: Any, resolution: Resolution | None) -> ClothMesh | None:
    """Inside an override's build: the mesh the old base `build_mesh` made (its `super().build_mesh()`); else None."""
    if _BUILDING.get() != id(scene) or not isinstance(scene.cloth, LegacySceneCloth):
        return None
    return scene.cloth.base.build(resolution)


def adopt_build_mesh_override(cls: type) -> None:
    """A subclass overriding `build_mesh` (deprecated): move the override aside, to be its cloth's mesh."""
    override = cls.__dict__.get("build_mesh")
    if override is None:
        return
    setattr(cls, OVERRIDE, override)
    delattr(cls, "build_mesh")
    warnings.warn(
        f"{cls.__qualname__} overrides SceneSpec.build_mesh, deprecated since clods-bench {DEPRECATED_SINCE} and removed "
        f"in {REMOVED_IN}: move the mesh into a Cloth (a frozen dataclass whose build(resolution) returns it) and give "
        f"the scene cloth=YourCloth(...) ({GUIDE})",
        PluginAPIDeprecationWarning,
        stacklevel=3,
    )


def is_legacy_call(args: tuple[Any, ...], kwargs: dict[str, Any]) -> bool:
    """Does this SceneSpec(...) call use the pre-1.0 form (kind= or a kind string in third place)?"""
    return any(k in kwargs for k in OLD_KEYS) or (len(args) >= 3 and isinstance(args[2], str))


def translate_legacy_call(cls: type, args: tuple[Any, ...], kwargs: dict[str, Any], stacklevel: int) -> dict[str, Any]:
    """The keyword arguments of today's SceneSpec for a pre-1.0 call, with its deprecation warning."""
    named = dict(zip(OLD_ORDER, args))
    twice = sorted(set(named) & set(kwargs))
    if twice or len(args) > len(OLD_ORDER):
        raise ClodsError(f"SceneSpec got {twice or 'too many positional arguments'} twice", where=f"scene {named.get('name')}")
    named.update(kwargs)
    where = f"scene {named.get('name')}"
    if "cloth" in named:
        raise ClodsError("gives both cloth= and the deprecated kind=/size=/default_resolution=", where=where,
                         hint=f"keep cloth= only ({GUIDE})")  # fmt: skip
    kind = named.pop("kind", None)
    old = {k: _tuple(named.pop(k, OLD_DEFAULTS[k])) for k in ("size", "default_resolution")}
    override = getattr(cls, OVERRIDE, None)
    if override is None and kind not in ("flag", "cylinder"):
        raise ClodsError(
            f"kind={kind!r} (a deprecated argument) names no cloth: the scene has no build_mesh override and kind='flag' "
            "and 'cylinder' are the only built-in ones",
            where=where, hint=f"give cloth= a Cloth whose build(resolution) returns the mesh; see {GUIDE}",
        )  # fmt: skip
    base: Cloth = (FlagCloth if kind == "flag" else CylinderCloth)(size=old["size"], default_resolution=old["default_resolution"])
    shown = ", ".join(f"{k}={v!r}" for k, v in {"kind": kind, **old}.items())
    if override is None:
        instead = f"cloth={type(base).__name__}(size={old['size']!r}, default_resolution={old['default_resolution']!r})"
    else:
        instead = f"cloth=...) with a Cloth whose build(resolution) returns the mesh of {cls.__qualname__}.build_mesh"
    warnings.warn(
        f"SceneSpec({shown}) is deprecated since clods-bench {DEPRECATED_SINCE} and removed in {REMOVED_IN}: write "
        f"SceneSpec(..., {instead}{')' if override is None else ''} ({GUIDE})",
        PluginAPIDeprecationWarning,
        stacklevel=stacklevel + 1,
    )
    named["cloth"] = base if override is None else LegacySceneCloth(base=base, legacy_kind=str(kind))
    return named


def bind_legacy_cloth(scene: Any) -> None:
    """Point a scene's `LegacySceneCloth` at the scene (a copy of the cloth if it belongs to another one)."""
    cloth = getattr(scene, "cloth", None)
    if isinstance(cloth, LegacySceneCloth) and cloth.scene is not scene:
        object.__setattr__(scene, "cloth", dataclasses.replace(cloth, scene=scene))
    elif not isinstance(cloth, LegacySceneCloth) and getattr(type(scene), OVERRIDE, None) is not None:
        override_cloth = LegacySceneCloth(base=cloth, legacy_kind=cloth.kind, scene=scene)  # a 1.0 scene overriding build_mesh
        object.__setattr__(scene, "cloth", override_cloth)
