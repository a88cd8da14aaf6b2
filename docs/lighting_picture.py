"""Make docs/lighting_flag_lit.png: one ci frame of the flag unlit and of flag-lit (same mesh), and its shading alone.

Usage (after generating both ci datasets into DATA):
    python docs/lighting_picture.py DATA TRAJ FRAME CAMERA OUT.png     # docs/data/scenes.md: DATA 3 20 1
"""

from __future__ import annotations

import sys

import numpy as np
from PIL import Image

from clods_bench.benchmark.core.config import load_config
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.generate import make_cameras, resolution_of
from clods_bench.datasets.rasterizer import RasterSettings, render_views
from clods_bench.datasets.scenes import get_scene
from clods_bench.datasets.store import DatasetStore

UP = 4  # 64 px frames shown at 256 px (nearest neighbour); the shading panel is rendered at 256 px


def main(root: str, traj: int, t: int, cam: int, out: str) -> None:
    """Write the three panels side by side to `out`."""
    flag_cfg = load_config("ci", overrides=[f"data.root={root}"])
    lit_cfg = load_config("ci", overrides=[f"data.root={root}", "data.scene=flag-lit"])
    flag, lit = DatasetStore.open(flag_cfg.data.dataset_dir()), DatasetStore.open(lit_cfg.data.dataset_dir())
    mesh_traj = lit.load_trajectory(traj)
    if not np.array_equal(flag.load_trajectory(traj).world_pos, mesh_traj.world_pos):
        raise SystemExit("flag and flag-lit trajectories differ")
    scene = get_scene("flag-lit")
    mesh = scene.build_mesh(resolution_of(lit_cfg.data))
    c = make_cameras(lit_cfg.data, mesh)[cam]
    K = np.array(c.K, float)
    K[:2] *= UP
    big = Camera(K, c.R, c.t, c.width * UP, c.height * UP)
    grey = np.full((2, 2, 3), 0.85, np.float32)
    shade = render_views(mesh_traj.world_pos[t], mesh_traj.cells, mesh.texture_uv(), grey, [big], RasterSettings(2, light=scene.light))[0]
    gap = np.full((c.height * UP, 4, 3), 255, np.uint8)
    panels = [np.kron(s.load_frames(traj)[t, cam], np.ones((UP, UP, 1), np.uint8)) for s in (flag, lit)]
    row = np.concatenate([panels[0], gap, panels[1], gap, np.clip(np.rint(shade * 255), 0, 255).astype(np.uint8)], axis=1)
    Image.fromarray(row).save(out, optimize=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])
