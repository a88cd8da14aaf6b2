"""The OpenCV world-to-camera <-> NeRF/OpenGL camera-to-world conversion, checked against geometry computed independently."""

from __future__ import annotations

import numpy as np
import pytest

from clods_bench.datasets.cameras import Camera, camera_rig, look_at
from clods_bench.datasets.nerf import camera_from_c2w_gl, camera_to_c2w_gl, check_c2w, intrinsics_dict
from clods_bench.errors import ClodsError


def _camera(eye=(3.0, -2.0, 1.5), target=(0.2, 0.1, -0.3)) -> Camera:
    R, t = look_at(np.array(eye), np.array(target))
    K = np.array([[100.0, 0.0, 30.5], [0.0, 90.0, 20.25], [0.0, 0.0, 1.0]])
    return Camera(K, R, t, 64, 48)


def test_c2w_places_the_camera_and_points_minus_z_at_the_target() -> None:
    eye, target = np.array([3.0, -2.0, 1.5]), np.array([0.2, 0.1, -0.3])
    c2w = camera_to_c2w_gl(_camera(eye, target))
    assert np.allclose(c2w[:3, 3], eye, atol=1e-12)  # translation = camera centre
    forward = (target - eye) / np.linalg.norm(target - eye)
    assert np.allclose(-c2w[:3, 2], forward, atol=1e-12)  # OpenGL cameras look along -z
    assert c2w[:3, 1] @ np.array([0.0, 0.0, 1.0]) > 0  # OpenGL +y is image up: towards world up (z) for look_at
    assert np.allclose(c2w[3], [0, 0, 0, 1]) and np.isclose(np.linalg.det(c2w[:3, :3]), 1.0)


def test_a_world_point_has_flipped_y_and_z_in_opengl_camera_coordinates() -> None:
    cam = _camera()
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 3))
    cv = cam.world_to_camera(pts)
    gl = (np.linalg.inv(camera_to_c2w_gl(cam)) @ np.c_[pts, np.ones(20)].T).T[:, :3]
    assert np.allclose(gl, cv * [1.0, -1.0, -1.0], atol=1e-12)


def test_round_trip_is_exact_to_1e_12_for_a_whole_rig() -> None:
    for cam in [_camera(), *camera_rig(7, np.array([0.0, 0.0, 1.0]), 4.0, 40, 40)]:
        back = camera_from_c2w_gl(camera_to_c2w_gl(cam), intrinsics_dict(cam), "test")
        for key in ("K", "R", "t"):
            assert np.abs(getattr(back, key) - getattr(cam, key)).max() < 1e-12
        assert (back.width, back.height) == (cam.width, cam.height)
        assert np.allclose(back.project(np.array([[0.1, 0.2, 0.9]]))[0], cam.project(np.array([[0.1, 0.2, 0.9]]))[0])


@pytest.mark.parametrize(
    ("matrix", "message"),
    [
        (np.zeros((4, 4)), "last row"),
        (np.diag([1.0, 1.0, 0.0, 1.0]), "not invertible"),
        (np.diag([2.0, 2.0, 2.0, 1.0]), "not a proper rotation"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "not a proper rotation"),
        ([[1, 2], [3, 4]], "4x4"),
        ("identity", "4x4"),
        (np.full((4, 4), np.nan), "finite"),
    ],
)
def test_bad_matrices_are_refused_naming_the_field(matrix, message) -> None:
    with pytest.raises(ClodsError, match=message) as info:
        check_c2w(matrix, "t.json: frames[3].transform_matrix")
    assert info.value.where == "t.json: frames[3].transform_matrix"


def test_a_3x4_matrix_is_completed() -> None:
    c2w = camera_to_c2w_gl(_camera())
    assert np.array_equal(check_c2w(c2w[:3].tolist(), "x"), c2w)
