"""Where does the first non-finite gradient of the stage-0 surfel fit on gsplat come from? Needs CUDA and gsplat.

The bent flag of tests/benchmark/clods/test_stage0.py, fitted with the gsplat surfel backend: hooks on the inputs
and outputs of gsplat's `rasterize_to_pixels_2dgs` print the first non-finite gradients (which tensor, which
surfels, their ray transforms), and every 20 calls the largest gradient magnitudes, so a NaN is traced to gsplat's
backward or to the gradients fed into it. `--variant drop` also replaces the non-finite entries of gsplat's input
gradients by 0 (counting them) and scores the reconstructed sheet as the test does.

    python examples/gpu/surfel_nan.py [--variant plain|drop]
"""

import argparse
import time

import gsplat.cuda._wrapper as W
import numpy as np
import torch

from clods_bench.benchmark.clods.stage0 import Stage0Config, reconstruct_initial_mesh
from clods_bench.benchmark.scoring.cross_topology import attach
from clods_bench.datasets.cameras import camera_rig
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.rasterizer import RasterSettings, render_views
from clods_bench.datasets.textures import make_named_texture

parser = argparse.ArgumentParser()
parser.add_argument("--variant", choices=("plain", "drop"), default="plain")
variant = parser.parse_args().variant
orig = W.rasterize_to_pixels_2dgs
state = {"call": 0, "reported": 0, "dropped": 0, "bad_calls": 0, "max": {}}
NAMES_IN = ["means2d", "ray_transforms", "colors", "opacities", "normals", "densify"]
NAMES_OUT = ["render", "alpha", "normal", "distort", "median"]


def report(call, kind, name, g, inputs):
    if state["reported"] >= 6:
        return
    state["reported"] += 1
    bad = ~torch.isfinite(g)
    print(f"call {call}: non-finite grad of {kind} '{name}' shape {tuple(g.shape)}: {int(bad.sum())} entries", flush=True)
    if kind == "input" and g.dim() >= 2:
        rows = torch.nonzero(bad.reshape(g.shape[0], g.shape[1], -1).any(-1))[:3].tolist()
        for c, i in rows:
            M = inputs[1][c, i].detach().cpu().numpy()
            print(f"  cam {c} surfel {i}: means2d {inputs[0][c, i].tolist()} opac {float(inputs[3][c, i]):.4f}\n  M {M.tolist()}"
                  f"\n  grad {g[c, i].reshape(-1).tolist()[:9]}", flush=True)


def input_hook(call, name, inputs):
    def hook(g):
        if g is None:
            return None
        finite = torch.isfinite(g)
        mx = float(g[finite].abs().max()) if bool(finite.any()) else float("nan")
        state["max"][name] = max(state["max"].get(name, 0.0), mx)
        if bool(finite.all()):
            return None
        report(call, "input", name, g, inputs)
        if variant == "drop":
            state["dropped"] += int((~finite).sum())
            return torch.where(finite, g, torch.zeros_like(g))
        return None

    return hook


def wrapped(means2d, ray_transforms, colors, opacities, normals, densify, *args, **kw):
    state["call"] += 1
    call = state["call"]
    inputs = (means2d, ray_transforms, colors, opacities, normals, densify)
    outs = orig(means2d, ray_transforms, colors, opacities, normals, densify, *args, **kw)
    for name, t in zip(NAMES_IN, inputs):
        if t.requires_grad:
            t.register_hook(input_hook(call, name, inputs))
    for name, t in zip(NAMES_OUT, outs):
        if t.requires_grad:
            t.register_hook(lambda g, n=name: (report(call, "output (incoming)", n, g, inputs) if g is not None and not torch.isfinite(g).all() else None))
        if not torch.isfinite(t).all():
            print(f"call {call}: non-finite FORWARD output {name}", flush=True)
    if call % 20 == 0:
        print(f"call {call}: largest finite input-gradient magnitudes so far " + ", ".join(f"{k} {v:.3g}" for k, v in state["max"].items()), flush=True)
    return outs


W.rasterize_to_pixels_2dgs = wrapped
flag = make_flag_mesh(9, 5, 1.0, 0.5)
x = flag.rest_pos.copy()
x[:, 1] = 0.15 * np.sin(np.pi * x[:, 0])
cams = camera_rig(6, np.array([0.5, 0.0, 0.25]), 2.2, 48, 48)
images = render_views(x, flag.cells, flag.texture_uv(), make_named_texture("procedural", seed=0), cams, RasterSettings(supersample=2))
t0 = time.time()
try:
    mesh, stats = reconstruct_initial_mesh(images, cams, Stage0Config(iterations=200, num_surfels=800, backend="gsplat"), 45)
    err = attach(x, mesh.rest_pos, mesh.cells).distance
    print(f"variant {variant}: finished in {time.time() - t0:.1f} s, {mesh.num_nodes} nodes, attached-point RMSE "
          f"{float(np.sqrt(np.mean(err**2))):.4f} m (test bound 0.04), {state['dropped']} non-finite gradient entries dropped", flush=True)
except Exception as exc:  # noqa: BLE001
    print(f"variant {variant}: stopped: {type(exc).__name__} {str(exc)[:300]} after {state['call']} raster calls", flush=True)
