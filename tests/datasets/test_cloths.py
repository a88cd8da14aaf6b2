"""Scene cloths: the generic mesh cloth equals the built-in flag, files load, handles move, bad meshes are named."""

from __future__ import annotations

import dataclasses
import math
import pickle
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from clods_bench.datasets.cloth_solver import SolverParams
from clods_bench.datasets.cloths import FlagCloth, MeshCloth, mesh_cloth_from_file
from clods_bench.datasets.generate import scene_fingerprint
from clods_bench.datasets.meshes import export_sequence, make_flag_mesh
from clods_bench.datasets.scenes import BUILTIN_SCENES, SceneSpec, get_scene, simulate_scene
from clods_bench.datasets.types import HANDLE, NORMAL, Trajectory
from clods_bench.errors import ClodsError

QUIET = SolverParams(air_density=0.0, air_drag=0.0)


def flag_as_mesh_cloth(nx: int = 6, ny: int = 4) -> MeshCloth:
    """The built-in flag's arrays handed over as a plain triangle mesh."""
    m = make_flag_mesh(nx, ny)
    return MeshCloth(cells=m.cells, rest_pos=m.rest_pos, handles=np.flatnonzero(m.node_type == HANDLE), mesh_pos=m.mesh_pos)


def scene_of(cloth, **fields) -> SceneSpec:
    return SceneSpec("mine", "a test scene", cloth, fields.pop("params", QUIET), **fields)


def test_builtin_fingerprints_are_those_of_the_scenes_before_clothes_were_plugins():
    """Computed with the code before this change (kind/size/default_resolution were scene fields): old datasets stay valid."""
    before = {
        "flag": "60b8812c6740f168",
        "flag-stiff": "7402f8d61202f4bf",
        "flag-storm": "a9beba1a6b15fc73",
        "flag-large-dt": "b5f41d2606cbeb1a",
        "cylinder": "f75be01112fc1481",
    }
    assert {s.name: scene_fingerprint(s) for s in BUILTIN_SCENES if s.name in before} == before  # later scenes came later


def test_mesh_cloth_simulates_exactly_like_the_builtin_flag():
    flag = get_scene("flag")
    mine = dataclasses.replace(flag, cloth=flag_as_mesh_cloth())
    a = simulate_scene(flag, flag.build_mesh((6, 4)), 8, seed=5)
    b = simulate_scene(mine, mine.build_mesh(), 8, seed=5)
    np.testing.assert_array_equal(a.world_pos, b.world_pos)
    np.testing.assert_array_equal(a.mesh_pos, b.mesh_pos)
    assert (a.meta["kind"], b.meta["kind"]) == ("flag", "mesh")
    assert mine.build_mesh((30, 30)).num_nodes == 24  # one resolution


def test_mesh_cloth_identity_covers_every_array_element_and_pickles():
    cloth = flag_as_mesh_cloth()
    scene = scene_of(cloth)
    rest = cloth.rest_pos.copy()
    rest[7, 1] += 1e-9
    assert scene_fingerprint(scene_of(dataclasses.replace(cloth, rest_pos=rest))) != scene_fingerprint(scene)
    assert scene_fingerprint(scene_of(dataclasses.replace(cloth, handles=cloth.handles[:-1]))) != scene_fingerprint(scene)
    again = pickle.loads(pickle.dumps(scene))  # generation workers receive the scene pickled
    assert scene_fingerprint(again) == scene_fingerprint(scene)


def test_cloth_from_obj_takes_mesh_pos_from_uvs_and_handles_from_the_top(tmp_path):
    m = make_flag_mesh(5, 4, 2.0, 1.0)
    traj = Trajectory(m.cells, m.mesh_pos, m.node_type, np.stack([m.rest_pos, m.rest_pos]).astype(np.float32), 0.02)
    path = export_sequence(traj, tmp_path)[0]  # UVs = mesh_pos normalised to [0,1]^2
    cloth = mesh_cloth_from_file(path, top_tol=1e-6)
    mesh = scene_of(cloth).build_mesh()
    np.testing.assert_allclose(mesh.mesh_pos, m.mesh_pos, atol=1e-5)  # uv scaled back to metres
    np.testing.assert_array_equal(np.flatnonzero(mesh.node_type == HANDLE), np.flatnonzero(m.rest_pos[:, 2] > 0.999))
    assert mesh.uv is not None and mesh.uv.min() >= 0.0 and mesh.uv.max() <= 1.0


@dataclass(frozen=True, eq=False)
class SwayingCurtain(MeshCloth):
    """A mesh cloth whose handles sway along x: start + (A sin(2 pi t / T), 0, 0)."""

    kind: ClassVar[str] = "swaying"
    amplitude: float = 0.2
    period: float = 0.5

    def handle_positions(self, t: float, start: np.ndarray) -> np.ndarray:
        return start + np.array([self.amplitude * math.sin(2.0 * math.pi * t / self.period), 0.0, 0.0])


def test_prescribed_handles_follow_their_trajectory_in_recorded_time():
    cloth = SwayingCurtain(**{f.name: getattr(flag_as_mesh_cloth(5, 3), f.name) for f in dataclasses.fields(MeshCloth)})
    scene = scene_of(cloth, warmup_time=0.1, rotation_range=(0.3, 0.3))
    mesh = scene.build_mesh()
    traj = simulate_scene(scene, mesh, 10, seed=0)
    handles = mesh.node_type == HANDLE
    start = traj.world_pos[0, handles].astype(np.float64) - [0.2 * math.sin(2 * math.pi * 0.1 / 0.5), 0.0, 0.0]
    for k in range(10):
        t = 0.1 + k * scene.dt  # frame 0 is recorded after the warm-up
        np.testing.assert_allclose(traj.world_pos[k, handles], cloth.handle_positions(t, start), atol=1e-6)
    assert np.ptp(traj.world_pos[:, handles, 0], axis=0).min() > 0.2  # they really move
    assert traj.meta["kind"] == "swaying"


def _bad(cloth, match: str, **fields) -> None:
    with pytest.raises(ClodsError, match=match) as info:
        scene_of(cloth, **fields).build_mesh()
    assert info.value.where is not None and info.value.where.startswith("scene mine")


SHEET = make_flag_mesh(3, 3, 1.0, 1.0)  # 9 nodes, 8 triangles, handles 0, 3, 6


def sheet(**changes) -> MeshCloth:
    base = MeshCloth(cells=SHEET.cells, rest_pos=SHEET.rest_pos, handles=[0, 3, 6], mesh_pos=SHEET.mesh_pos)
    return dataclasses.replace(base, **changes)


def test_a_valid_sheet_passes():
    mesh = scene_of(sheet()).build_mesh()
    assert mesh.num_nodes == 9 and list(np.flatnonzero(mesh.node_type == HANDLE)) == [0, 3, 6]


def test_edge_of_three_triangles_is_named():
    rest = np.vstack([SHEET.rest_pos, [[0.5, 0.5, 0.3]]])
    mp = np.vstack([SHEET.mesh_pos, [[0.5, 0.5]]])
    cells = np.vstack([SHEET.cells, [[0, 4, 9]]])  # edge (0, 4) is a diagonal of two triangles already
    assert {0, 4} <= set(SHEET.cells[0]) | set(SHEET.cells[1])
    _bad(sheet(cells=cells, rest_pos=rest, mesh_pos=mp), r"edges are shared by more than two triangles .*edge \(0, 4\)")


def test_inconsistent_orientation_is_named():
    cells = SHEET.cells.copy()
    cells[5] = cells[5][::-1]
    _bad(sheet(cells=cells), "not consistently oriented")


def test_bowtie_node_is_named():
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 0, -1]], float)
    cells = np.array([[0, 1, 2], [0, 3, 4]])
    _bad(sheet(cells=cells, rest_pos=rest, mesh_pos=rest[:, [0, 2]], handles=[1]), "separate fans .*node 0")


def test_zero_area_triangle_is_named():
    rest = SHEET.rest_pos.copy()
    assert SHEET.cells[0].tolist() == [0, 1, 4]
    rest[1] = 0.5 * (rest[0] + rest[4])  # node 1 onto the segment 0-4: face 0 collapses to a line
    _bad(sheet(rest_pos=rest), "1 triangles have zero rest area .*face 0")


def test_repeated_node_and_duplicate_face_are_named():
    cells = SHEET.cells.copy()
    cells[2] = [1, 1, 4]
    _bad(sheet(cells=cells), "repeat a node, first is face 2")
    cells = np.vstack([SHEET.cells, SHEET.cells[3][::-1]])
    _bad(sheet(cells=cells), "1 duplicate faces, first duplicates face 3")


def test_handles_out_of_range_missing_or_undeclared_are_named():
    _bad(sheet(handles=[0, 9]), r"handle indices out of range \[0, 9\), first is 9")
    _bad(sheet(handles=[]), "declares has_handles but the cloth has no handle")
    _bad(sheet(), "3 handle nodes but the scene declares has_handles=False", has_handles=False)
    free = scene_of(sheet(handles=[]), has_handles=False, init_speed_range=(0.0, 0.0), warmup_time=0.0)
    mesh = free.build_mesh()
    assert mesh.node_type.tolist() == [NORMAL] * 9
    traj = simulate_scene(free, mesh, 6, seed=1)  # a free cloth needs no handles: it falls
    com_z = traj.world_pos[:, :, 2].mean(axis=1)
    assert np.all(np.diff(com_z) < 0) and np.isfinite(traj.world_pos).all()


def test_mesh_pos_of_wrong_shape_or_scale_is_named():
    _bad(sheet(mesh_pos=SHEET.rest_pos), r"mesh_pos has shape \(9, 3\), expected \(V, 2\) = \(9, 2\)")
    _bad(sheet(mesh_pos=SHEET.mesh_pos[:5]), r"mesh_pos has shape \(5, 2\)")
    _bad(sheet(mesh_pos=100.0 * SHEET.mesh_pos), "mesh_pos edge lengths differ from the rest shape's")  # centimetres


def test_node_in_no_triangle_is_named():
    rest = np.vstack([SHEET.rest_pos, [[3.0, 0.0, 0.0]]])
    _bad(sheet(rest_pos=rest, mesh_pos=np.vstack([SHEET.mesh_pos, [[3.0, 0.0]]])), "1 nodes belong to no triangle .*node 9")


@dataclass(frozen=True, eq=False)
class Jumpy(MeshCloth):
    kind: ClassVar[str] = "jumpy"
    offset: float = 0.5
    rows: int = 3

    def handle_positions(self, t: float, start: np.ndarray) -> np.ndarray:
        return (start + self.offset)[: self.rows]


def test_handle_motion_that_jumps_or_has_the_wrong_shape_is_named():
    fields = {f.name: getattr(sheet(), f.name) for f in dataclasses.fields(MeshCloth)}
    _bad(Jumpy(**fields), "0.5 m away from the handles' start")
    _bad(Jumpy(**fields, offset=0.0, rows=2), r"has shape \(2, 3\), expected \(3, 3\)")


def test_a_cloth_that_is_not_a_cloth_is_named():
    with pytest.raises(ClodsError, match="cloth is a int"):
        SceneSpec("old", "not a cloth", 42, QUIET)  # type: ignore[arg-type]
    with pytest.warns(DeprecationWarning, match="write SceneSpec\\(..., cloth=FlagCloth"):  # the pre-0.2 positional kind
        assert isinstance(SceneSpec("old", "positional kind", "flag", QUIET).cloth, FlagCloth)  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match="scene mine: cloth: unknown resolution 'huge'"):
        scene_of(FlagCloth()).build_mesh("huge")
