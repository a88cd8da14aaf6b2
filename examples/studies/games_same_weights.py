"""Are clods-bench's GaMeS Gaussians the authors'? Same mesh, same weights and factors, float64: means, covariances,
and their gradients with respect to the vertices and the scale factors.

The reference is the authors' code, github.com/waczjoan/gaussian-mesh-splatting at commit
1722f7089c7ad94e875876c0216b10f89f11f026 (a git checkout, given as the argument): `GaussianMeshModel.update_alpha`
and `prepare_scaling_rot` (games/mesh_splatting/scene/gaussian_mesh_model.py) build the Gaussians of a mesh, and
the 3DGS base class turns scales and quaternions into covariances (`get_covariance`). Only those functions run:
the CUDA extension and the ply reader their modules import are replaced by empty stand-ins, the model modules'
packages are entered without their `__init__` (which loads datasets and arguments), and `utils.general_utils`
gets a view of torch whose `zeros` makes float64 CPU tensors (the code asks for float32 on "cuda"). clods-bench's
side is `mesh_gaussians.anchor_gaussians`. Two comparisons on a bent 7 x 5 flag with 3 Gaussians a face:

- as the code runs: `_alpha` = clods-bench's barycentric weights (the code adds 1e-8 before normalising them),
  `eps_s0` = 1e-8 (added to every norm; the normal axis is eps (f + 1)); clods-bench's normal scale 1e-6;
- epsilons matched: the code's weights set to the same barycentric weights exactly, `eps_s0` = 1e-300 and
  clods-bench's normal scale 0, so that what is left is the formula.

    python examples/studies/games_same_weights.py /path/to/gaussian-mesh-splatting \
        --out results/studies/games_same_weights/differences.txt
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import torch

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.plugins.renderers.mesh_gaussians import anchor_gaussians, barycentric_layout

REFERENCE = "github.com/waczjoan/gaussian-mesh-splatting"
COMMIT = "1722f7089c7ad94e875876c0216b10f89f11f026"
MODEL = "games/mesh_splatting/scene/gaussian_mesh_model.py"
K = 3  # Gaussians per face


def fail(message: str) -> None:
    print(message)
    raise SystemExit(1)


def check_checkout(path: Path) -> None:
    """One clear line and exit unless `path` is a git checkout of the reference at COMMIT."""
    if not (path / MODEL).is_file():
        fail(f"{path}: no {MODEL} here; expected a checkout of {REFERENCE}")
    head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        fail(f"{path}: not a git checkout ({head.stderr.strip()}); expected {REFERENCE} at {COMMIT}")
    if head.stdout.strip() != COMMIT:
        fail(f"{path}: checkout is at {head.stdout.strip()}, this study knows {REFERENCE} at {COMMIT}")


def load_reference(path: Path) -> type:
    """The authors' GaussianMeshModel class, importable on a CPU, its helpers in float64."""
    sys.path.insert(0, str(path))
    for name in ("plyfile", "simple_knn", "simple_knn._C"):  # imported by the 3DGS base module, unused here
        stub = types.ModuleType(name)
        stub.PlyData = stub.PlyElement = stub.distCUDA2 = None
        sys.modules[name] = stub
    for package in ("scene", "games", "games.mesh_splatting", "games.mesh_splatting.scene", "games.mesh_splatting.utils"):
        module = types.ModuleType(package)  # the package, without running its __init__
        module.__path__ = [str(path / package.replace(".", "/"))]
        sys.modules[package] = module
    general = importlib.import_module("utils.general_utils")
    view = types.ModuleType("torch_float64_cpu")
    view.__dict__.update({k: getattr(torch, k) for k in dir(torch) if not k.startswith("__")})
    view.zeros = lambda *shape, dtype=None, device=None: torch.zeros(*shape, dtype=torch.float64)
    general.torch = view
    return importlib.import_module("games.mesh_splatting.scene.gaussian_mesh_model").GaussianMeshModel


def scene(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(vertices (V,3), faces (F,3), barycentric weights (K,3), scale factors (F*K,)) of a bent flag."""
    mesh = make_flag_mesh(7, 5, length=1.2, height=0.8)
    rng = np.random.default_rng(seed)
    verts = mesh.rest_pos + rng.normal(0.0, 0.05, mesh.rest_pos.shape)
    factors = rng.uniform(0.5, 2.0, len(mesh.cells) * K)
    return torch.as_tensor(verts), torch.as_tensor(mesh.cells, dtype=torch.int64), torch.as_tensor(barycentric_layout(K)), torch.as_tensor(factors)


def compare(model_cls: type, matched: bool) -> dict[str, float]:
    """Largest |ours - reference| / max |reference| per quantity."""
    verts, faces, bary, factors = scene()
    g = torch.Generator().manual_seed(1)
    w_mean, w_cov = torch.rand(len(factors), 3, generator=g, dtype=torch.float64), torch.rand(len(factors), 6, generator=g, dtype=torch.float64)
    upper = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]  # the code's strip_symmetric order

    ref = model_cls(0)
    ref.vertices = verts.clone().requires_grad_(True)
    ref.faces = faces
    ref._alpha = bary.expand(len(faces), K, 3).clone()
    ref._scale = factors.clone()[:, None].requires_grad_(True)
    ref.eps_s0 = 1e-300 if matched else 1e-8
    ref.update_alpha()
    if matched:  # the weights themselves, not the code's relu(w) + 1e-8 renormalised
        ref.alpha = bary.expand(len(faces), K, 3)
        ref._calc_xyz()
    ref.prepare_scaling_rot()
    r_means, r_cov = ref.get_xyz, ref.get_covariance()
    (r_means * w_mean).sum().add((r_cov * w_cov).sum()).backward()

    v, f = verts.clone().requires_grad_(True), factors.clone().requires_grad_(True)
    means, cov, _ = anchor_gaussians(v, faces, bary, f, 0.0 if matched else 1e-6)
    o_cov = torch.stack([cov[:, i, j] for i, j in upper], dim=1)
    (means * w_mean).sum().add((o_cov * w_cov).sum()).backward()

    def rel(a: torch.Tensor, b: torch.Tensor) -> float:
        return float((a - b).abs().max() / b.abs().max())

    return {
        "means": rel(means.detach(), r_means.detach()),
        "covariances": rel(o_cov.detach(), r_cov.detach()),
        "d/d vertices": rel(v.grad, ref.vertices.grad),
        "d/d scale factors": rel(f.grad, ref._scale.grad[:, 0]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", type=Path, help=f"a git checkout of {REFERENCE} at {COMMIT}")
    parser.add_argument("--out", type=Path, help="also write the table here")
    args = parser.parse_args()
    check_checkout(args.checkout)
    model_cls = load_reference(args.checkout)
    lines = [f"reference: {REFERENCE} @ {COMMIT}", "max |clods-bench - reference| / max |reference|, float64, 48 faces x 3 Gaussians", ""]
    worst = 0.0
    for matched in (False, True):
        lines.append("epsilons matched (the formula):" if matched else "as the code runs (its 1e-8 epsilons, normal scale 1e-6 here):")
        for key, value in compare(model_cls, matched).items():
            lines.append(f"  {key:<20} {value:.3e}")
            worst = max(worst, value) if matched else worst
    lines += ["", f"worst with epsilons matched: {worst:.3e} ({'within' if worst <= 1e-10 else 'OUTSIDE'} 1e-10)"]
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    sys.exit(0 if worst <= 1e-10 else 1)


if __name__ == "__main__":
    main()
