"""The pre-1.0 scene form (`SceneSpec(kind=...)`, `build_mesh` overrides) keeps working with a deprecation warning that
says what to write, and makes the same data as today's form; what it cannot express is refused in one line."""

from __future__ import annotations

import dataclasses
import pickle
import warnings

import numpy as np
import pytest

from clods_bench.api_version import PluginAPIDeprecationWarning
from clods_bench.datasets.cloths import CylinderCloth, FlagCloth
from clods_bench.datasets.generate import scene_fingerprint
from clods_bench.datasets.meshes import make_cylinder_mesh, make_flag_mesh
from clods_bench.datasets.scenes import SceneSpec, get_scene
from clods_bench.datasets.types import HANDLE
from clods_bench.errors import ClodsError

GUIDE = "docs/plugins/migrating.md#scenes-kind-and-build_mesh"


def test_kind_flag_is_todays_flag_cloth_with_the_same_fingerprint() -> None:
    flag = get_scene("flag")
    with pytest.warns(PluginAPIDeprecationWarning) as caught:
        old = SceneSpec(name="flag", description="written the old way", kind="flag", params=flag.params)
    assert issubclass(PluginAPIDeprecationWarning, DeprecationWarning)
    (message,) = [str(w.message) for w in caught]
    assert message == ("SceneSpec(kind='flag', size=(2.0, 1.0), default_resolution='flagsimple') is deprecated since "
                       "clods-bench 0.2.0 and removed in 0.3.0: write SceneSpec(..., cloth=FlagCloth(size=(2.0, 1.0), "
                       f"default_resolution='flagsimple')) ({GUIDE})")  # fmt: skip
    assert caught[0].filename == __file__  # points at the plugin's line, not at clods-bench
    assert old.cloth == FlagCloth() and scene_fingerprint(old) == scene_fingerprint(flag)  # same data, datasets reused


def test_positional_kind_cylinder_keeps_the_builtin_cylinders_fingerprint() -> None:
    cyl = get_scene("cylinder")
    with pytest.warns(PluginAPIDeprecationWarning, match=r"cloth=CylinderCloth\(size=\(0.3, 1.0\), default_resolution=\(32, 16\)\)"):
        old = SceneSpec("cylinder", "old", "cylinder", cyl.params, 0.02, 1, False, True, False, True, [0.3, 1.0], [32, 16],
                        perturb_amplitude=0.005, wind_speed_range=(0.5, 2.0), wind_direction_spread=cyl.wind_direction_spread)  # fmt: skip
    assert old.cloth == CylinderCloth(size=(0.3, 1.0), default_resolution=(32, 16))
    assert scene_fingerprint(old) == scene_fingerprint(cyl)


with warnings.catch_warnings(record=True) as BANNER_CLASS_WARNINGS:  # module level: pickling needs an importable class
    warnings.simplefilter("always")

    @dataclasses.dataclass(frozen=True)
    class Banner(SceneSpec):
        """An old plugin's scene: a subclass with a field of its own, overriding build_mesh on top of the flag."""

        drop: float = 0.1

        def build_mesh(self, resolution=None):
            mesh = super().build_mesh(resolution)  # the old base: the flag of kind "flag"
            rest = mesh.rest_pos.copy()
            rest[:, 2] -= self.drop * rest[:, 0] / rest[:, 0].max()
            return dataclasses.replace(mesh, rest_pos=rest)


def test_build_mesh_override_becomes_the_cloths_mesh() -> None:
    (message,) = [str(w.message) for w in BANNER_CLASS_WARNINGS if issubclass(w.category, PluginAPIDeprecationWarning)]
    assert message.startswith("Banner overrides SceneSpec.build_mesh") and message.endswith(f"cloth=YourCloth(...) ({GUIDE})")
    with pytest.warns(PluginAPIDeprecationWarning, match=r"returns the mesh of .*Banner.build_mesh"):
        scene = Banner(name="banner", description="d", kind="flag", params=get_scene("flag").params, size=(1.0, 0.5),
                       default_resolution=(6, 4), drop=0.2)  # fmt: skip
    mesh = scene.build_mesh()  # validated like any cloth's mesh
    flat = make_flag_mesh(6, 4, 1.0, 0.5)
    np.testing.assert_array_equal(mesh.cells, flat.cells)
    np.testing.assert_allclose(mesh.rest_pos[:, 2], flat.rest_pos[:, 2] - 0.2 * flat.rest_pos[:, 0] / 1.0, rtol=0, atol=1e-12)
    assert scene.kind == "flag" and scene.size == (1.0, 0.5) and scene.build_mesh((4, 3)).num_nodes == 12
    assert (mesh.node_type == HANDLE).sum() == 4  # the pole edge, as the flag has it

    moved = dataclasses.replace(scene, drop=0.0)  # the copy's cloth builds from the copy, not from the original
    np.testing.assert_allclose(moved.build_mesh().rest_pos, flat.rest_pos, atol=1e-12)
    again = pickle.loads(pickle.dumps(moved))  # generation workers get scenes pickled
    assert again.cloth.scene is again and again == moved
    np.testing.assert_allclose(again.build_mesh().rest_pos, flat.rest_pos, atol=1e-12)


def test_override_without_super_and_a_kind_of_its_own() -> None:
    with pytest.warns(PluginAPIDeprecationWarning):

        class Tube(SceneSpec):
            def build_mesh(self, resolution=None):
                return make_cylinder_mesh(8, 4, 0.2, 0.5)

        scene = Tube(name="tube", description="d", kind="tube", params=get_scene("flag").params)
    assert scene.kind == "tube" and scene.build_mesh().num_nodes == 32
    assert scene_fingerprint(scene) != scene_fingerprint(get_scene("cylinder"))


def test_what_the_old_form_cannot_say_is_refused_in_one_line() -> None:
    params = get_scene("flag").params
    with pytest.raises(ClodsError) as exc:
        SceneSpec(name="banner", description="d", kind="banner", params=params)
    assert exc.value.message.startswith("scene banner: kind='banner' (a deprecated argument) names no cloth")
    assert f"give cloth= a Cloth whose build(resolution) returns the mesh; see {GUIDE}" in exc.value.message
    with pytest.raises(ClodsError, match="gives both cloth= and the deprecated kind="):
        SceneSpec(name="x", description="d", cloth=FlagCloth(), kind="flag", params=params)


def test_todays_form_raises_no_warning() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = SceneSpec("flag", "d", FlagCloth(), get_scene("flag").params)
        dataclasses.replace(scene, dt=0.05)
    assert scene.size == (2.0, 1.0)  # old overrides read it; the public API does not list it
    with pytest.raises(AttributeError, match="no attribute 'volume'"):
        scene.volume  # noqa: B018
