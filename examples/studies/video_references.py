"""Loading the video predictors' reference code from the user's checkouts, and carrying weights over to it one to one.

Used by `video_same_weights.py`. Nothing of the references is copied here: each module is imported from the
checkout the user names, after its commit is checked. OpenSTL's package `__init__` files import training machinery
(Lightning, data sets); only `openstl.modules` (the blocks) and single files of `openstl.models` and
`openstl.methods` are loaded, the latter's `diff_div_reg` as the one function it is.
"""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
import types
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

KNOWN = {
    "openstl": ("chengtan9907/OpenSTL", "c74deb5d4c3da585291f9f18281f3fefdbba3a54"),
    "simvp": ("A4Bio/SimVP", "4dcd4451282e014573ca4346ced8223e342f7893"),
    "mau": ("ZhengChang467/MAU", "9e5461cfbacf20cc4323839730f06a9c09d98187"),
}
"""Reference key -> (GitHub repository, the commit this study knows)."""


class StudyError(Exception):
    """One clear line for the user: a checkout, a file or a tensor that is not what the study needs."""


def check_checkout(key: str, path: Path) -> Path:
    """The checkout at `path` after checking it is the known commit of reference `key`."""
    repo, commit = KNOWN[key]
    if not path.is_dir():
        raise StudyError(f"{repo} checkout not found: {path}")
    try:
        head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        raise StudyError(f"{path} is not a git checkout of {repo} (this study knows commit {commit})") from None
    if head != commit:
        raise StudyError(f"{path} is at commit {head}; this study knows {repo} at commit {commit} (git -C {path} checkout {commit})")
    return path


def need_file(root: Path, rel: str) -> Path:
    """root/rel, or a StudyError naming the missing file."""
    f = root / rel
    if not f.is_file():
        raise StudyError(f"missing reference file: {f}")
    return f


def import_from(root: Path, module: str, stub_packages: tuple[str, ...] = ()) -> Any:
    """Import `module` with `root` first on sys.path; each of `stub_packages` is registered as an empty package over its
    folder, so its `__init__.py` (with imports the study does not need) does not run."""
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    for name in stub_packages:
        if name not in sys.modules:
            pkg = types.ModuleType(name)
            pkg.__path__ = [str(root / name.replace(".", "/"))]
            sys.modules[name] = pkg
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise StudyError(f"importing {module} from {root} failed: {exc} (the reference needs it installed in this Python)") from None


def function_from_source(file: Path, name: str, env: dict[str, Any], cls: str | None = None) -> Callable[..., Any]:
    """The function `name` (a method of class `cls` if given) of a source file, compiled on its own in namespace `env`
    (the rest of the file, its imports included, does not run)."""
    tree = ast.parse(file.read_text(), filename=str(file))
    scopes = [n.body for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == cls] if cls else [tree.body]
    for body in scopes:
        for item in body:
            if isinstance(item, ast.FunctionDef) and item.name == name:
                code = compile(ast.Module(body=[item], type_ignores=[]), str(file), "exec")
                scope = dict(env)
                exec(code, scope)  # noqa: S102 - the user's own checkout of the reference
                return scope[name]
    raise StudyError(f"{file} has no function {f'{cls}.' if cls else ''}{name}")


def randomize(model: torch.nn.Module, seed: int) -> None:
    """Move every floating tensor of the state away from its initial value (float64 numpy draws): weights by 20 % of
    their spread, biases and norm shifts by 0.1, norm scales around 1, layer scales in [0.5, 1.5] (so the TAU blocks
    are no near-identities), BatchNorm statistics to non-trivial means and variances."""
    rng = np.random.default_rng(seed)
    with torch.no_grad():
        for name, t in model.state_dict().items():
            if not t.is_floating_point():
                continue
            u = torch.from_numpy(rng.uniform(-1.0, 1.0, tuple(t.shape))).to(t.dtype)
            if name.endswith("running_var"):
                t.copy_(1.0 + 0.5 * u)
            elif "layer_scale" in name:
                t.copy_(1.0 + 0.5 * u)
            elif t.numel() > 1 and float(t.std()) > 0:
                t.add_(0.2 * float(t.std()) * u)
            else:
                t.add_(0.1 * u)


Rules = list[tuple[str, Any]]
"""(regex over one of our state names, its replacement: a template or a function of the match) pairs, first match wins."""


def map_state(ours: torch.nn.Module, ref: torch.nn.Module, rules: Rules, unused: tuple[str, ...] = ()) -> tuple[dict[str, str], list[str]]:
    """Copy every state tensor of `ours` into `ref` under the name the regex `rules` give; each reference tensor must be
    filled exactly once except those matching `unused`. Returns (our name -> reference name, the reference's tensors
    left out: held by it and never used). Any name or shape that does not map is a StudyError naming the tensor."""
    src, dst = ours.state_dict(), ref.state_dict()
    filled: dict[str, str] = {}
    for key, t in src.items():
        target = next((re.sub(p, r, key) for p, r in rules if re.fullmatch(p, key)), None)
        if target is None or target not in dst:
            raise StudyError(f"cannot map tensor {key} {tuple(t.shape)}: no reference tensor {target or '(no rule)'}")
        if dst[target].shape != t.shape:
            raise StudyError(f"cannot map tensor {key}: shape {tuple(t.shape)}, reference {target} has {tuple(dst[target].shape)}")
        if target in filled.values():
            raise StudyError(f"reference tensor {target} mapped twice (second: {key})")
        filled[key] = target
        dst[target] = t.detach().clone()
    used = set(filled.values())
    left = [k for k in dst if k not in used and not any(re.fullmatch(p, k) for p in unused)]
    if left:
        raise StudyError(f"reference tensor {left[0]} {tuple(dst[left[0]].shape)} has no counterpart ({len(left)} unmapped)")
    ref.load_state_dict(dst)
    return filled, [k for k in dst if k not in used]


def grad_diff(ours: torch.nn.Module, ref: torch.nn.Module, names: dict[str, str]) -> tuple[float, float]:
    """(largest |difference| of the parameter gradients over all mapped parameters, largest |gradient| of ours)."""
    ref_params = dict(ref.named_parameters())
    worst, scale = 0.0, 0.0
    for key, p in ours.named_parameters():
        g, h = p.grad, ref_params[names[key]].grad
        if g is None or h is None:
            raise StudyError(f"no gradient for {key} (ours: {g is not None}, reference {names[key]}: {h is not None})")
        worst, scale = max(worst, max_diff(g, h)), max(scale, float(g.abs().max()))
    return worst, scale


def max_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest absolute difference of two tensors of one shape."""
    if a.shape != b.shape:
        raise StudyError(f"outputs differ in shape: {tuple(a.shape)} against the reference's {tuple(b.shape)}")
    return float((a - b).abs().max())
