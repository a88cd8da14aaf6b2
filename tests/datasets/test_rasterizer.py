"""Ground-truth rasterizer against independent facts: coverage, fill rule, texture, perspective,
projection, z-buffer, lighting, clipping and input errors."""

import subprocess
import sys

import numpy as np
import pytest

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.rasterizer import DirectionalLight, RasterSettings, render, render_depth, render_views
from clods_bench.errors import ClodsError

SS1 = RasterSettings(supersample=1, background=(1.0, 1.0, 1.0))
BLACK = np.zeros((2, 2, 3), np.float32)


def front_camera(w: int = 32, h: int = 32, f: float = 16.0) -> Camera:
    """Camera at the origin looking along +z (world = camera frame), cx = W/2, cy = H/2."""
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    return Camera(K, np.eye(3), np.zeros(3), w, h)


def unproject(cam: Camera, uv: np.ndarray, z: np.ndarray | float) -> np.ndarray:
    """World points (camera frame) at depth z that project onto pixel coordinates uv."""
    uv = np.atleast_2d(np.asarray(uv, float))
    z = np.broadcast_to(np.asarray(z, float), (uv.shape[0],))
    x = (uv[:, 0] - cam.K[0, 2]) * z / cam.K[0, 0]
    y = (uv[:, 1] - cam.K[1, 2]) * z / cam.K[1, 1]
    return np.stack([x, y, z], axis=1)


def coverage(verts, cells, cam, settings=SS1) -> np.ndarray:
    """Bool mask of pixels drawn (black texture on a white background)."""
    img = render(verts, cells, np.zeros((len(verts), 2)), BLACK, cam, settings)
    assert np.all((img == 0.0) | (img == 1.0))
    return img[..., 0] == 0.0


def edge_values(p2d: np.ndarray, cam: Camera) -> np.ndarray:
    """(3,H,W) edge functions of a screen triangle at every pixel centre, oriented positive inside."""
    cc, rr = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5, indexing="xy")
    out = []
    for i in range(3):
        a, b = p2d[(i + 1) % 3], p2d[(i + 2) % 3]
        out.append((b[0] - a[0]) * (rr - a[1]) - (b[1] - a[1]) * (cc - a[0]))
    area = (p2d[1, 0] - p2d[0, 0]) * (p2d[2, 1] - p2d[0, 1]) - (p2d[1, 1] - p2d[0, 1]) * (p2d[2, 0] - p2d[0, 0])
    return np.array(out) * np.sign(area)


# --- coverage and the fill rule -------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_single_triangle_covers_exactly_the_pixel_centres_inside(seed):
    rng = np.random.default_rng(seed)
    cam = front_camera(40, 30, 25.0)
    screen = rng.uniform(-10, 50, (3, 2))  # may reach outside the image
    verts = unproject(cam, screen, rng.uniform(1.0, 3.0, 3))
    p2d, _ = cam.project(verts)
    e = edge_values(p2d, cam)
    inside, borderline = (e > 0).all(0), (np.abs(e) < 1e-9).any(0)
    mask = coverage(verts, np.array([[0, 1, 2]]), cam)
    assert borderline.sum() <= 2
    np.testing.assert_array_equal(mask[~borderline], inside[~borderline])
    flipped = coverage(verts, np.array([[0, 2, 1]]), cam)  # two-sided: winding does not matter
    np.testing.assert_array_equal(flipped, mask)


def test_mesh_covers_every_pixel_exactly_once():
    """Triangles of a jittered grid (vertices on a half-pixel lattice, so many pixel centres lie
    exactly on edges and vertices), each rendered alone: the masks tile the rectangle."""
    rng = np.random.default_rng(1)
    cam = front_camera(32, 32, 16.0)
    n, step, lo = 7, 4.0, 4.0
    gx, gy = np.meshgrid(lo + step * np.arange(n), lo + step * np.arange(n), indexing="xy")
    jitter = rng.integers(-3, 4, (n, n, 2)) * 0.5
    jitter[[0, -1], :, :] = 0.0
    jitter[:, [0, -1], :] = 0.0  # keep the boundary a rectangle
    screen = np.stack([gx, gy], -1) + jitter
    verts = unproject(cam, screen.reshape(-1, 2), 1.0)  # exact: f and z are powers of two
    assert np.array_equal(cam.project(verts)[0], screen.reshape(-1, 2))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    diag = rng.random(a.size) < 0.5
    cells = np.concatenate([np.where(diag[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1)),
                            np.where(diag[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))])  # fmt: skip
    count = sum(coverage(verts, cells[i : i + 1], cam).astype(int) for i in range(len(cells)))
    hi = lo + step * (n - 1)
    centres = np.arange(32) + 0.5
    strictly_in = ((centres > lo) & (centres < hi))[:, None] & ((centres > lo) & (centres < hi))[None, :]
    strictly_out = ~(((centres >= lo) & (centres <= hi))[:, None] & ((centres >= lo) & (centres <= hi))[None, :])
    assert count.max() == 1
    assert np.all(count[strictly_in] == 1)
    assert np.all(count[strictly_out] == 0)
    np.testing.assert_array_equal(coverage(verts, cells, cam), count == 1)


def test_float_meshes_with_varying_depth_cover_every_pixel_exactly_once():
    """Jittered (non-folding) grids with inexact vertex positions (thirds of a pixel, random
    floats) and random depths: per-triangle masks never overlap and leave no gap inside."""
    cam = front_camera(64, 64, 16.0)
    n, step, lo = 9, 7.0, 4.0
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    cells = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    gx, gy = np.meshgrid(lo + step * np.arange(n), lo + step * np.arange(n), indexing="xy")
    inner = slice(int(lo) + 1, int(lo + step * (n - 1)))
    for seed in range(40):
        rng = np.random.default_rng(seed)
        jitter = rng.integers(-4, 5, (n, n, 2)) / 3.0 if seed % 2 else rng.uniform(-1.5, 1.5, (n, n, 2))
        jitter[[0, -1]] = 0.0
        jitter[:, [0, -1]] = 0.0
        verts = unproject(cam, (np.stack([gx, gy], -1) + jitter).reshape(-1, 2), rng.uniform(1.0, 3.0, n * n))
        count = sum(coverage(verts, cells[i : i + 1], cam).astype(int) for i in range(len(cells)))
        assert count.max() == 1, seed
        assert np.all(count[inner, inner] == 1), seed


def test_two_triangles_sharing_a_diagonal_through_pixel_centres():
    cam = front_camera(16, 16, 16.0)
    screen = np.array([[2.5, 2.5], [12.5, 2.5], [12.5, 12.5], [2.5, 12.5]])  # corners on pixel centres
    verts = unproject(cam, screen, 1.0)
    m1 = coverage(verts, np.array([[0, 1, 2]]), cam)
    m2 = coverage(verts, np.array([[0, 2, 3]]), cam)
    assert not (m1 & m2).any()
    both = m1 | m2
    # the closed square [2.5, 12.5]^2 holds 11 x 11 centres; top-left rule keeps the top and left sides
    expected = np.zeros((16, 16), bool)
    expected[2:12, 2:12] = True
    np.testing.assert_array_equal(both, expected)
    assert m1.sum() + m2.sum() == 100


# --- texture and perspective ----------------------------------------------------------------


def quad(cam, screen_rect, z=1.0):
    x0, y0, x1, y1 = screen_rect
    verts = unproject(cam, np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float), z)
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return verts, np.array([[0, 1, 2], [0, 2, 3]]), uv


def test_head_on_quad_reproduces_its_texture_texel_for_pixel():
    """Quad spans pixels [8, 56)^2, texture is 48x48: every pixel centre hits a texel centre."""
    rng = np.random.default_rng(0)
    tex = rng.random((48, 48, 3)).astype(np.float32)
    cam = front_camera(64, 64, 64.0)
    verts, cells, uv = quad(cam, (8, 8, 56, 56), z=2.0)
    img = render(verts, cells, uv, tex, cam, SS1)
    np.testing.assert_allclose(img[8:56, 8:56], tex, atol=2e-5)  # float32 texture, float64 weights
    assert np.all(img[:8] == 1.0) and np.all(img[56:] == 1.0) and np.all(img[:, :8] == 1.0)


def test_head_on_quad_with_supersampling_is_the_box_filtered_bilinear_texture():
    """With s=2 the four samples of a pixel sit +-1/4 texel off a texel centre; bilinear weights
    are 3/4 and 1/4 per axis, so the pixel is the texture blurred with [1/8, 3/4, 1/8] (wrapping)."""
    rng = np.random.default_rng(1)
    tex = rng.random((24, 24, 3)).astype(np.float32)
    cam = front_camera(32, 32, 32.0)
    verts, cells, uv = quad(cam, (4, 4, 28, 28))
    img = render(verts, cells, uv, tex, cam, RasterSettings(supersample=2))
    blur = tex.astype(np.float64)
    for axis in (0, 1):
        blur = 0.75 * blur + 0.125 * (np.roll(blur, 1, axis) + np.roll(blur, -1, axis))
    np.testing.assert_allclose(img[4:28, 4:28], blur, atol=2e-5)


def test_bilinear_sampling_between_texel_centres():
    """Quad twice the texture size: pixel centres fall at texel quarter positions."""
    tex = np.zeros((2, 2, 3), np.float32)
    tex[0, 1] = 1.0  # only texel (row 0, col 1) is white
    cam = front_camera(8, 8, 8.0)
    verts, cells, uv = quad(cam, (2, 2, 6, 6))
    img = render(verts, cells, uv, tex, cam, SS1)[2:6, 2:6, 0]
    # pixel centre j maps to texel coordinate x = (j + 0.5)/4 * 2 - 0.5 = -0.25, 0.25, 0.75, 1.25;
    # texel centres are at 0 and 1 and wrap (x = -0.25 is 1/4 of the way from texel 1 (= -1) to 0)
    wx = np.array([0.25, 0.25, 0.75, 0.75])  # weight of column 1 in the blend
    wy = np.array([0.75, 0.75, 0.25, 0.25])  # weight of row 0
    np.testing.assert_allclose(img, wy[:, None] * wx[None, :], atol=1e-6)


def test_perspective_correct_uv_on_a_tilted_quad():
    """Quad in the plane z = 3 + 1.5 x; the UV at each pixel is where its ray meets the plane."""
    cam = front_camera(64, 64, 40.0)
    a, b = 3.0, 1.5
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    verts = np.column_stack([corners, a + b * corners[:, 0]])
    uv = (corners + 1.0) / 2.0
    n = 256  # a linear ramp texture: colour = (u, v, 0) exactly under bilinear interpolation
    ramp = (np.arange(n) + 0.5) / n
    tex = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:, None], 0.0 * ramp[None, :]), -1).astype(np.float32)
    img = render(verts, np.array([[0, 1, 2], [0, 2, 3]]), uv, tex, cam, SS1)
    cc, rr = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5, indexing="xy")
    dx, dy = (cc - 32) / 40.0, (rr - 32) / 40.0
    t = a / (1.0 - b * dx)  # ray (dx, dy, 1) * t meets z = a + b x
    u_true, v_true = (t * dx + 1) / 2, (t * dy + 1) / 2
    interior = (np.minimum(u_true, v_true) > 2.0 / n) & (np.maximum(u_true, v_true) < 1 - 2.0 / n)
    assert interior.sum() > 500
    np.testing.assert_allclose(img[..., 0][interior], u_true[interior], atol=1e-5)
    np.testing.assert_allclose(img[..., 1][interior], v_true[interior], atol=1e-5)
    # the test can tell: affine (screen-space) interpolation would be off by much more
    p2d, _ = Camera.project(cam, verts)
    u_affine = (cc - p2d[0, 0]) / (p2d[1, 0] - p2d[0, 0])  # along the top edge, roughly
    assert np.abs(u_affine - u_true)[interior].max() > 0.05
    depth = render_depth(verts, np.array([[0, 1, 2], [0, 2, 3]]), cam)
    np.testing.assert_allclose(depth[interior], t[interior], rtol=1e-12)
    assert np.isinf(depth[~(img[..., 2] < 1.0)]).all()


# --- projection, z-buffer, lighting -----------------------------------------------------------


def test_rasterized_point_lands_where_the_camera_projects_it():
    target = np.array([0.3, -0.2, 1.0])
    cams = camera_rig(5, target, 3.0, 40, 40, fov_deg=40.0)
    point = target + np.array([0.11, 0.07, -0.05])
    for cam in cams:
        (u, v), = cam.project(point[None])[0]
        # a small triangle facing the camera, corners ~2 px from the point: it contains every
        # point within 0.5 px (per axis) of the projection, so the centre of pixel (int(v), int(u))
        right, down = cam.R[0], cam.R[1]
        size = 2.0 * cam.world_to_camera(point[None])[0, 2] / cam.K[0, 0]
        verts = point + size * np.stack([-right - down, right - down, 2 * down])
        mask = coverage(verts, np.array([[0, 1, 2]]), cam)
        assert mask[int(v), int(u)] and mask.sum() <= 20
        depth = render_depth(verts, np.array([[0, 1, 2]]), cam)
        assert np.isfinite(depth).sum() == mask.sum()


def test_nearer_triangle_wins_regardless_of_order():
    cam = front_camera(32, 32, 16.0)
    screen = np.array([[4.0, 4.0], [28.0, 6.0], [10.0, 28.0]])
    near_tri = unproject(cam, screen, 2.0)
    far_tri = unproject(cam, np.array([[2.0, 20.0], [30.0, 2.0], [26.0, 30.0]]), np.array([2.5, 4.0, 6.0]))
    verts = np.concatenate([near_tri, far_tri])
    tex = np.zeros((1, 2, 3), np.float32)
    tex[0, 0], tex[0, 1] = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)  # u < 0.5 red, u > 0.5 blue
    uv = np.array([[0.25, 0.5]] * 3 + [[0.75, 0.5]] * 3)
    both = np.array([[0, 1, 2], [3, 4, 5]])
    red_alone = coverage(verts, both[:1], cam)
    for cells in (both, both[::-1]):
        img = render(verts, cells, uv, tex, cam, SS1)
        red = (img[..., 0] > 0.99) & (img[..., 2] < 0.01)  # barycentrics sum to 1 up to rounding
        np.testing.assert_array_equal(red, red_alone)
    depth = render_depth(verts, both[::-1], cam)
    np.testing.assert_allclose(depth[red_alone], 2.0)


def test_interpenetrating_triangles_split_where_depths_cross():
    cam = front_camera(32, 32, 16.0)
    sq = np.array([[2.0, 2.0], [30.0, 2.0], [30.0, 30.0], [2.0, 30.0]])
    flat = unproject(cam, sq, 2.0)  # z = 2
    xy = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    tilted = np.column_stack([xy, 2.0 + 0.5 * xy[:, 0]])  # z = 2 + x/2: nearer than `flat` where x < 0
    depth_flat = render_depth(flat, [[0, 1, 2], [0, 2, 3]], cam)
    depth_both = render_depth(np.concatenate([flat, tilted]), [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], cam)
    depth_tilt = render_depth(tilted, [[0, 1, 2], [0, 2, 3]], cam)
    np.testing.assert_array_equal(depth_both, np.minimum(depth_flat, depth_tilt))
    assert (depth_tilt < depth_flat).sum() > 50 and (depth_flat < depth_tilt).sum() > 50


@pytest.mark.parametrize("winding", [[0, 1, 2], [0, 2, 1]])
def test_two_sided_lambert(winding):
    cam = front_camera(16, 16, 16.0)
    verts = unproject(cam, np.array([[1.0, 1.0], [15.0, 1.0], [1.0, 15.0]]), 1.0)  # normal along z
    white = np.ones((2, 2, 3), np.float32)
    cells = np.array([winding])
    for direction, expected in [((0, 0, 1), 0.7), ((0, 0, -3), 0.7), ((1, 0, 0), 0.2), ((0, 1, 1), 0.2 + 0.5 / np.sqrt(2))]:
        light = DirectionalLight(direction=np.array(direction, float), ambient=0.2, diffuse=0.5)
        img = render(verts, cells, np.zeros((3, 2)), white, cam, RasterSettings(supersample=1, light=light))
        np.testing.assert_allclose(img[3, 3], expected, atol=1e-6)
        assert np.all(img[14, 14] == 1.0)  # background is not lit
    no_light = render(verts, cells, np.zeros((3, 2)), white, cam, SS1)
    assert np.all(no_light == 1.0)


# --- degenerate inputs and clipping -------------------------------------------------------------


def test_zero_area_triangles_draw_nothing():
    cam = front_camera(16, 16, 16.0)
    verts = unproject(cam, np.array([[1.5, 1.5], [8.5, 8.5], [14.5, 14.5], [3.0, 3.0]]), 1.0)
    cells = np.array([[0, 1, 2], [3, 3, 3], [0, 0, 1]])
    assert not coverage(verts, cells, cam).any()
    assert np.isinf(render_depth(verts, cells, cam)).all()


def test_near_plane_clipping_matches_the_ray_plane_intersection():
    """A plane z = 0.2 + x crossing near = 0.5 in view: drawn exactly where its depth is >= near."""
    cam = front_camera(48, 48, 24.0)
    near = 0.5
    corners = np.array([[-0.6, -0.5], [1.0, -0.5], [1.0, 0.5], [-0.6, 0.5]])
    verts = np.column_stack([corners, 0.2 + corners[:, 0]])  # z from -0.4 (behind) to 1.2
    cells = np.array([[0, 1, 2], [0, 2, 3]])
    settings = RasterSettings(supersample=1, near=near)
    mask = coverage(verts, cells, cam, settings)
    cc, rr = np.meshgrid(np.arange(48) + 0.5, np.arange(48) + 0.5, indexing="xy")
    dx, dy = (cc - 24) / 24.0, (rr - 24) / 24.0
    with np.errstate(divide="ignore"):
        t = np.where(dx < 1, 0.2 / (1 - dx), np.inf)
    x, y = t * dx, t * dy
    hit = (t >= near) & (x <= 1.0) & (np.abs(y) <= 0.5)
    borderline = (np.abs(t - near) < 1e-9) | (np.abs(x - 1.0) < 1e-9) | (np.abs(np.abs(y) - 0.5) < 1e-9)
    assert hit.sum() > 100 and (~hit & (t > 0) & (np.abs(y) <= 0.5)).sum() > 50  # part really clipped
    np.testing.assert_array_equal(mask[~borderline], hit[~borderline])
    depth = render_depth(verts, cells, cam, near=near)
    np.testing.assert_allclose(depth[hit & ~borderline], t[hit & ~borderline], rtol=1e-9)
    # triangles sharing a clipped edge still cover each pixel once
    m1, m2 = coverage(verts, cells[:1], cam, settings), coverage(verts, cells[1:], cam, settings)
    assert not (m1 & m2).any() and np.array_equal(m1 | m2, mask)


@pytest.mark.parametrize(
    "zs", [(-1.0, 2.0, 3.0), (-1.0, -2.0, 3.0), (0.0, 0.0, 0.0), (-1.0, -1.0, -1.0), (1e-12, 1e-3, 5.0), (0.0, 1e-300, 1.0)]
)
def test_vertices_at_or_behind_the_camera_give_finite_images(zs):
    cam = front_camera(16, 16, 16.0)
    verts = np.array([[-0.5, -0.5, zs[0]], [0.6, -0.4, zs[1]], [0.1, 0.7, zs[2]]])
    img = render(verts, np.array([[0, 1, 2]]), np.random.default_rng(0).random((3, 2)), np.ones((4, 4, 3)), cam)
    assert img.shape == (16, 16, 3) and np.isfinite(img).all() and img.min() >= 0 and img.max() <= 1
    depth = render_depth(verts, np.array([[0, 1, 2]]), cam)
    assert not np.isnan(depth).any() and (depth[np.isfinite(depth)] >= 1e-3).all()


def test_huge_coordinates_do_not_crash():
    cam = front_camera(16, 16, 16.0)
    verts = np.array([[-1e12, -1e12, 1.0], [1e12, -1e12, 1.0], [0.0, 1e12, 1.0]])
    mask = coverage(verts, np.array([[0, 1, 2]]), cam)
    assert mask.all()


# --- API, multi-view, errors -------------------------------------------------------------------


def test_render_views_matches_single_renders_and_settings():
    rng = np.random.default_rng(3)
    verts = rng.normal(size=(30, 3)) * 0.5
    cells = rng.integers(0, 30, (40, 3))
    uv, tex = rng.random((30, 2)), rng.random((8, 8, 3)).astype(np.float32)
    cams = camera_rig(3, np.zeros(3), 4.0, 24, 20)
    settings = RasterSettings(supersample=3, background=(0.0, 0.5, 1.0), light=DirectionalLight((1.0, 2.0, -1.0)))
    imgs = render_views(verts, cells, uv, tex, cams, settings)
    assert imgs.shape == (3, 20, 24, 3) and imgs.dtype == np.float32
    for cam, img in zip(cams, imgs):
        np.testing.assert_array_equal(render(verts, cells, uv, tex, cam, settings), img)
    np.testing.assert_allclose(imgs[:, 0, 0], [[0.0, 0.5, 1.0]] * 3)
    assert hash(settings) == hash(RasterSettings(3, (0.0, 0.5, 1.0), 1e-3, DirectionalLight(np.array([1.0, 2.0, -1.0]))))


def test_threaded_render_views_is_the_serial_render_bit_for_bit(monkeypatch):
    """Views drawn in 2, 3 or 8 threads (more threads than views) equal the one-thread images exactly, shadows and
    flat-coloured faces included; the workers' cap limits the threads; 0 threads is one clear error."""
    from clods_bench.datasets.rasterizer import render_threads

    rng = np.random.default_rng(5)
    verts = rng.normal(size=(40, 3)) * 0.5
    cells = rng.integers(0, 40, (60, 3))
    uv, tex = rng.random((40, 2)), rng.random((8, 8, 3)).astype(np.float32)
    colors = np.where(rng.random((60, 1)) < 0.3, rng.random((60, 3)), np.nan)
    cams = camera_rig(5, np.zeros(3), 4.0, 24, 20)
    settings = RasterSettings(supersample=2, light=DirectionalLight((1.0, 2.0, -1.0), shadow_map_size=64))
    serial = render_views(verts, cells, uv, tex, cams, settings, colors, threads=1)
    assert np.unique(serial).size > 50  # a textured, shaded picture, not a blank one
    for k in (2, 3, 8):
        np.testing.assert_array_equal(render_views(verts, cells, uv, tex, cams, settings, colors, threads=k), serial)
    monkeypatch.setenv("CLODS_BENCH_MAX_THREADS", "2")
    assert render_threads(8) == 2 and render_threads(1) == 1
    with pytest.raises(ClodsError, match="threads must be >= 1"):
        render_views(verts, cells, uv, tex, cams, settings, threads=0)


def test_bad_inputs_raise_clods_errors_naming_the_argument():
    cam = front_camera(8, 8, 8.0)
    verts = np.zeros((4, 3))
    cells = np.array([[0, 1, 2], [1, 2, 3]])
    uv, tex = np.zeros((4, 2)), np.ones((2, 2, 3))
    bad = verts.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ClodsError, match=r"verts.*index 2"):
        render(bad, cells, uv, tex, cam)
    for args, name in [
        ((np.zeros((4, 2)), cells, uv, tex), "verts"),
        ((verts, cells[:, :2], uv, tex), "cells"),
        ((verts, cells + 3, uv, tex), "cells"),
        ((verts, cells * 0.5, uv, tex), "cells"),
        ((verts, cells, uv[:3], tex), "uv"),
        ((verts, cells, uv, tex[..., :2]), "texture"),
    ]:
        with pytest.raises(ClodsError) as info:
            render(*args, cam)
        assert info.value.where == name
    bad_k = Camera(np.diag([0.0, 8.0, 1.0]), np.eye(3), np.zeros(3), 8, 8)
    with pytest.raises(ClodsError, match="focal"):
        render(verts, cells, uv, tex, bad_k)
    with pytest.raises(ClodsError, match=r"cameras\[1\]"):
        render_views(verts, cells, uv, tex, [cam, front_camera(9, 8)], RasterSettings())
    with pytest.raises(ClodsError, match="supersample"):
        render(verts, cells, uv, tex, cam, RasterSettings(supersample=0))
    with pytest.raises(ClodsError, match="direction"):
        render(verts, cells, uv, tex, cam, RasterSettings(light=DirectionalLight((0.0, 0.0, 0.0))))
    with pytest.raises(ClodsError, match="verts"):
        render_depth(bad, cells, cam)


def test_import_does_not_compile():
    code = (
        "import clods_bench.datasets.rasterizer as r\n"
        "ks = [r.rk.render_views_kernel, r.rk.depth_kernel, r.rk.raster_view]\n"
        "assert all(not k.signatures for k in ks), [k.signatures for k in ks]\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_bench_rasterizer_reports_on_the_flagsimple_mesh():
    """The benchmark's scene is the 3028-face flag, visibly on screen; speed itself is `clods-bench bench data`'s job."""
    from clods_bench.datasets.raster_bench import bench_rasterizer

    result = bench_rasterizer(num_views=4, size=64)
    assert result["num_faces"] > 2900 and result["coverage"] > 0.2
    assert result["ms_per_view"] > 0 and result["ms_per_view_one_thread"] > 0
    assert result["threads"] >= 1 and result["thread_speedup"] > 0


# --- flat face colours (obstacles) ------------------------------------------------------------


def _two_quads() -> tuple[np.ndarray, np.ndarray, Camera]:
    """Two side-by-side squares (2 triangles each) at depth 2 filling the left and right halves of a 32 x 32 view."""
    cam = front_camera()
    corners = unproject(cam, [[0, 0], [16, 0], [32, 0], [0, 32], [16, 32], [32, 32]], 2.0)
    cells = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    return corners, cells, cam


def test_flat_face_colours_replace_the_texture_exactly_where_set():
    """NaN rows keep the texture (identical to no face_colors); coloured faces show exactly their colour, also lit."""
    verts, cells, cam = _two_quads()
    uv = np.zeros((6, 2))
    tex = np.full((2, 2, 3), 0.25, np.float32)
    plain = render(verts, cells, uv, tex, cam, SS1)
    colors = np.full((4, 3), np.nan)
    colors[2:] = (0.1, 0.6, 0.9)
    img = render(verts, cells, uv, tex, cam, SS1, face_colors=colors)
    np.testing.assert_array_equal(img[:, :15], plain[:, :15])
    np.testing.assert_allclose(img[:, 17:], np.broadcast_to([0.1, 0.6, 0.9], img[:, 17:].shape), atol=1e-6)
    np.testing.assert_array_equal(render(verts, cells, uv, tex, cam, SS1, face_colors=np.full((4, 3), np.nan)), plain)
    lit = RasterSettings(supersample=1, light=DirectionalLight(direction=(0.0, 0.0, 1.0), ambient=0.2, diffuse=0.5, shadow_map_size=0))
    shaded = render(verts, cells, uv, tex, cam, lit, face_colors=colors)  # facing the light: ambient + diffuse = 0.7
    np.testing.assert_allclose(shaded[:, 17:], np.broadcast_to(0.7 * np.array([0.1, 0.6, 0.9]), shaded[:, 17:].shape), atol=1e-6)


def test_bad_face_colours_are_one_clear_error():
    verts, cells, cam = _two_quads()
    with pytest.raises(ClodsError, match=r"face_colors.*expected \(4, 3\)"):
        render(verts, cells, np.zeros((6, 2)), BLACK, cam, SS1, face_colors=np.zeros((3, 3)))
    with pytest.raises(ClodsError, match="face_colors.*in \\[0, 1\\]"):
        render(verts, cells, np.zeros((6, 2)), BLACK, cam, SS1, face_colors=np.full((4, 3), 2.0))


def test_the_cloth_casts_its_shadow_on_a_flat_coloured_obstacle():
    """Floor (flat colour, z = 3) under a textured square (z = 2, x in [-1.5, -0.5]) lit along d = (1, 0, 1)/sqrt(2):
    the floor is shadowed exactly for x in [-0.5, 0.5] (the square shifted by the 1 m depth gap), i.e. pixel columns
    13.3-18.7; lit floor elsewhere gets ambient + diffuse * |n . d|."""
    cam = front_camera()
    floor = unproject(cam, [[0, 0], [32, 0], [32, 32], [0, 32]], 3.0)
    square = np.array([[-1.5, -4.0, 2.0], [-0.5, -4.0, 2.0], [-0.5, 4.0, 2.0], [-1.5, 4.0, 2.0]])
    verts = np.concatenate([square, floor])
    cells = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    colors = np.full((4, 3), np.nan)
    colors[2:] = (0.5, 0.5, 0.5)
    light = DirectionalLight(direction=(1.0, 0.0, 1.0), ambient=0.2, diffuse=0.8, shadow_map_size=256)
    img = render(verts, cells, np.zeros((8, 2)), np.ones((2, 2, 3), np.float32), cam, RasterSettings(supersample=1, light=light), colors)
    row = img[16, :, 0]
    np.testing.assert_allclose(row[14:18], 0.5 * 0.2, atol=1e-6)  # in the square's shadow: ambient only
    np.testing.assert_allclose(row[21:31], 0.5 * (0.2 + 0.8 / np.sqrt(2.0)), atol=1e-6)  # lit floor
