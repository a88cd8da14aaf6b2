"""Pinhole cameras: projection by hand, look_at, the rig, intrinsics and validation errors."""

import math

import numpy as np
import pytest

from clods_bench.datasets.cameras import Camera, camera_rig, intrinsics_from_fov, look_at
from clods_bench.errors import ClodsError


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_project_matches_pinhole_by_hand():
    K = np.array([[100.0, 0.0, 40.0], [0.0, 120.0, 30.0], [0.0, 0.0, 1.0]])
    R = rot_z(0.3)
    t = np.array([0.1, -0.2, 3.0])
    cam = Camera(K, R, t, 80, 60)
    p = np.array([0.5, 0.25, -0.4])
    # x_cam = R p + t, written out component by component
    xc = [sum(R[i, j] * p[j] for j in range(3)) + t[i] for i in range(3)]
    u_hand = 100.0 * xc[0] / xc[2] + 40.0
    v_hand = 120.0 * xc[1] / xc[2] + 30.0
    uv, z = cam.project(p[None])
    np.testing.assert_allclose(uv[0], [u_hand, v_hand], rtol=1e-12)
    np.testing.assert_allclose(z[0], xc[2], rtol=1e-12)
    np.testing.assert_allclose(cam.center, -R.T @ t, atol=1e-12)
    assert cam.world_to_camera(cam.center[None]) == pytest.approx(np.zeros((1, 3)), abs=1e-12)


def test_optical_axis_hits_the_image_centre_and_pixel_centres():
    cam = Camera(intrinsics_from_fov(60.0, 64, 48), np.eye(3), np.zeros(3), 64, 48)
    uv, _ = cam.project(np.array([[0.0, 0.0, 5.0]]))
    np.testing.assert_allclose(uv[0], [32.0, 24.0])  # a pixel corner: between pixels 31 and 32
    # the ray through the centre of pixel (row 0, col 0) projects back onto (0.5, 0.5)
    fx, cx, cy = cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
    ray = np.array([(0.5 - cx) / fx, (0.5 - cy) / fx, 1.0])
    np.testing.assert_allclose(cam.project(2.0 * ray[None])[0][0], [0.5, 0.5], atol=1e-12)


def test_intrinsics_from_fov():
    K = intrinsics_from_fov(90.0, 100, 50)
    np.testing.assert_allclose(K, [[50.0, 0, 50.0], [0, 50.0, 25.0], [0, 0, 1]], atol=1e-12)
    # the edge of the horizontal field of view lands on the image border
    cam = Camera(intrinsics_from_fov(40.0, 100, 50), np.eye(3), np.zeros(3), 100, 50)
    u = cam.project(np.array([[math.tan(math.radians(20.0)), 0.0, 1.0]]))[0][0, 0]
    assert u == pytest.approx(100.0)
    for bad in (0.0, 180.0, -5.0):
        with pytest.raises(ClodsError, match="fov"):
            intrinsics_from_fov(bad, 10, 10)


def test_look_at_puts_target_at_centre_in_front_and_up_is_up():
    eye, target = np.array([3.0, -2.0, 1.5]), np.array([0.2, 0.1, 0.4])
    R, t = look_at(eye, target)
    cam = Camera(intrinsics_from_fov(45.0, 64, 64), R, t, 64, 64)
    cam.validate()
    uv, z = cam.project(np.stack([target, target + [0.0, 0.0, 0.1]]))
    np.testing.assert_allclose(uv[0], [32.0, 32.0], atol=1e-9)
    assert z[0] == pytest.approx(np.linalg.norm(target - eye))
    assert uv[1, 1] < uv[0, 1]  # world +z appears higher in the image (smaller row)
    np.testing.assert_allclose(cam.center, eye, atol=1e-12)


def test_look_at_straight_down_is_still_a_rotation():
    R, t = look_at(np.array([0.0, 0.0, 5.0]), np.zeros(3))
    Camera(np.eye(3), R, t, 4, 4).validate()
    np.testing.assert_allclose(R[2], [0.0, 0.0, -1.0], atol=1e-12)


def test_camera_rig_all_cameras_see_the_target_at_the_centre():
    target = np.array([1.0, 0.0, 0.5])
    cams = camera_rig(7, target, 4.0, 48, 32, fov_deg=35.0)
    assert len(cams) == 7
    centres = []
    for cam in cams:
        cam.validate()
        uv, z = cam.project(target[None])
        np.testing.assert_allclose(uv[0], [24.0, 16.0], atol=1e-9)
        assert z[0] == pytest.approx(4.0)
        centres.append(cam.center)
    dists = np.linalg.norm(np.array(centres) - target, axis=1)
    np.testing.assert_allclose(dists, 4.0)
    assert len({tuple(np.round(c, 6)) for c in centres}) == 7  # distinct positions
    with pytest.raises(ClodsError, match="num_cameras"):
        camera_rig(0, target, 4.0, 8, 8)


def test_dict_round_trip():
    cam = camera_rig(3, np.zeros(3), 2.0, 16, 12)[1]
    back = Camera.from_dict(cam.to_dict())
    for name in ("K", "R", "t"):
        np.testing.assert_array_equal(getattr(back, name), getattr(cam, name))
    assert (back.width, back.height) == (16, 12)


@pytest.mark.parametrize(
    "K, R, t, size, where",
    [
        (np.diag([0.0, 10.0, 1.0]), np.eye(3), np.zeros(3), (8, 8), "cam.K"),
        (np.diag([10.0, -1.0, 1.0]), np.eye(3), np.zeros(3), (8, 8), "cam.K"),
        (np.full((3, 3), np.nan), np.eye(3), np.zeros(3), (8, 8), "cam.K"),
        (np.eye(3), np.diag([1.0, 1.0, -1.0]), np.zeros(3), (8, 8), "cam.R"),
        (np.eye(3), 2 * np.eye(3), np.zeros(3), (8, 8), "cam.R"),
        (np.eye(3), np.eye(3), np.array([0.0, np.inf, 0.0]), (8, 8), "cam.t"),
        (np.eye(3), np.eye(3), np.zeros(3), (0, 8), "cam"),
    ],
)
def test_validate_names_the_bad_field(K, R, t, size, where):
    with pytest.raises(ClodsError) as info:
        Camera(K, R, t, *size).validate(where="cam")
    assert info.value.where == where


def test_validation_is_remembered_by_value_and_redone_after_a_change(monkeypatch) -> None:
    """A camera whose values passed is not checked again (renderers validate every call); a camera whose array was
    changed in place is checked again and its fault reported."""
    R, t = look_at(np.array([3.0, 0.0, 1.0]), np.zeros(3))
    cam = Camera(intrinsics_from_fov(50.0, 16, 16), R, t, 16, 16)
    cam.validate()
    calls = []
    real = Camera._check
    monkeypatch.setattr(Camera, "_check", lambda self, where: (calls.append(where), real(self, where)))
    Camera(cam.K.copy(), cam.R.copy(), cam.t.copy(), 16, 16).validate(where="again")
    assert calls == []
    cam.R[0, 0] = 5.0  # no longer a rotation
    with pytest.raises(ClodsError, match="proper rotation"):
        cam.validate(where="changed")
    assert calls == ["changed"]
