"""A misbehaving plugin, installed as a distribution, and a failing machine are named in one line: the plugin, the
stage and the seed; the cause (memory, permission), the path and the stage; a clods-bench bug says where to report it
and names the file its traceback was saved to."""

from __future__ import annotations

import errno
import os
import pickle
import re
import sys
import warnings
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from clods_bench import atomic
from clods_bench.benchmark.core.builders import data_splits
from clods_bench.benchmark.core.interfaces import CONTRACT_ULPS, RolloutInput
from clods_bench.benchmark.running import records
from clods_bench.cli import main
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import PluginError
from clods_bench.plugins.simulators.baselines import ConstantVelocity
from tests.conftest import TINY, tiny_config
from tests.plugin_packages import install, only_own_plugins

SOURCE = '''
import numpy as np
from clods_bench.api import PluginSpec, hookimpl

CLODS_BENCH_API = "1.0"


class Base:
    """Constant velocity that follows the contract; each subclass breaks one thing."""

    def fit(self, train, ctx):
        return {}

    def rollout(self, inp):
        x = np.repeat(inp.init_pos[1:2], inp.num_frames, axis=0)
        x[:2] = inp.init_pos
        kin = inp.kinematic_mask
        x[2:, kin] = inp.kinematic_pos[2:, kin]
        return x


class Raises(Base):
    def rollout(self, inp):
        raise ValueError("the mesh has 24 nodes, the model 25")


class Zeros(Base):
    def rollout(self, inp):
        return np.zeros((inp.num_frames, inp.node_type.shape[0], 3), np.float32)


class Nones(Base):
    def rollout(self, inp):
        return np.full((inp.num_frames, inp.node_type.shape[0], 3), None, dtype=object)


class MovesHandles(Base):
    def rollout(self, inp):
        x = super().rollout(inp)
        x[2:, inp.kinematic_mask] += 0.01
        return x


class FitOutOfMemory(Base):
    def fit(self, train, ctx):
        raise MemoryError("Unable to allocate 143. GiB for an array with shape (100000000, 128, 3) and data type float32")


class TorchOutOfMemory(Base):
    def fit(self, train, ctx):
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:117] data. DefaultCPUAllocator: not enough memory: you tried to "
                           "allocate 1099511627776 bytes.")


def build_raises(cfg, ctx):
    raise KeyError("weights")


@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name=name, description=name, build=lambda cfg, ctx, c=c: c()) for name, c in (
        ("raise-sim", Raises), ("zeros-sim", Zeros), ("none-sim", Nones), ("shift-sim", MovesHandles),
        ("oom-sim", FitOutOfMemory), ("torch-oom-sim", TorchOutOfMemory))] + [
        PluginSpec(name="build-sim", description="raises in build", build=build_raises)]
'''
HINT = "(return frames 0 and 1 and every non-NORMAL node's kinematic_pos unchanged)"
MEMORY = "use a smaller config (data sizes, batch_size, latent_size) or a machine with more memory"


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The misbehaving simulators installed as the distribution `misbehaving-sims` (a module and its dist-info)."""
    path = tmp_path_factory.mktemp("plugins") / "site"
    install(path, "misbehaving-sims", SOURCE)
    with only_own_plugins(path):
        try:
            yield path
        finally:
            sys.modules.pop("cbt_misbehaving_sims", None)


def _run(root: Path, sim: str) -> int:
    sets = (*TINY, f"data.root={root / 'data'}", f"runs_dir={root / 'runs'}")
    return main(["run", "cdg", "--sim", sim, *[a for s in sets for a in ("--set", s)]])


def _traceback_file(line: str) -> Path:
    found = re.search(r"(/\S+/clods-bench-traceback-\d{8}-\d{6}-\d+\.txt)", line)
    assert found, line
    return Path(found.group(1))


def test_a_plugin_that_raises_is_named_with_its_stage_and_seed(site: Path, tmp_path: Path, capsys) -> None:
    assert _run(tmp_path, "raise-sim") == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    saved = _traceback_file(line)
    assert line == (f"error: simulator 'raise-sim' raised ValueError during rollout (stage: rollout, seed 0): the mesh has 24 nodes, "
                    f"the model 25 (traceback: {saved})")  # fmt: skip
    assert saved.parent == (tmp_path / "runs").resolve() and "ValueError: the mesh has 24 nodes" in saved.read_text()
    assert _run(tmp_path, "build-sim") == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line == f"error: simulator 'build-sim' raised KeyError during build (stage: build, seed 0): 'weights' (traceback: {_traceback_file(line)})"


def _first_rollout_input(root: Path) -> RolloutInput:
    """What CDG rolls out first in the tiny config: the first viewed trajectory, all its frames."""
    cfg = tiny_config(root)
    traj = DatasetStore.open(cfg.data.dataset_dir()).load_trajectory(data_splits(cfg.data).viewed[0])
    return RolloutInput.from_trajectory(traj, cfg.data.num_steps)


def _xyz(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(v):.7g}" for v in p) + ")"


def test_a_rollout_that_changes_given_positions_is_a_contract_error(site: Path, tmp_path: Path, capsys) -> None:
    """All zeros (the given frames ignored) and handles moved by 1 cm: the first node and frame that differ, named."""
    assert _run(tmp_path, "zeros-sim") == 2
    inp = _first_rollout_input(tmp_path)
    given = inp.init_pos.astype(np.float32)
    kin = inp.kinematic_pos[:, inp.kinematic_mask]
    tol = CONTRACT_ULPS * float(np.spacing(np.float32(max(np.abs(given).max(), np.abs(kin).max()))))
    node = int(np.flatnonzero(np.abs(given[0]).max(axis=1) > tol)[0])  # frame 0's first node away from the origin
    kind = "HANDLE" if inp.node_type[node] == 3 else "NORMAL"
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: simulator 'zeros-sim': rollout changed given frame 0: node {node} ({kind}) is (0, 0, 0), given {_xyz(given[0, node])} "
        f"(tolerance {tol:.3g} m) {HINT}"
    )
    assert _run(tmp_path, "shift-sim") == 2
    handle = int(np.flatnonzero(inp.kinematic_mask)[0])
    moved = (inp.kinematic_pos[2, handle].astype(np.float64) + 0.01).astype(np.float32)
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: simulator 'shift-sim': rollout moved kinematic node {handle} (HANDLE) at frame 2: {_xyz(moved)}, given "
        f"{_xyz(inp.kinematic_pos[2, handle])} (tolerance {tol:.3g} m) {HINT}"
    )


def test_a_rollout_of_none_objects_is_named_without_a_numpy_warning(site: Path, tmp_path: Path, capsys) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert _run(tmp_path, "none-sim") == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "error: simulator 'none-sim': rollout returned an array of dtype object, expected a (T,V,3) float32 array of positions"
    )
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]


@pytest.mark.parametrize(
    ("sim", "cause"),
    [
        ("oom-sim", "MemoryError: Unable to allocate 143. GiB for an array with shape (100000000, 128, 3) and data type float32"),
        ("torch-oom-sim", "RuntimeError: [enforce fail at alloc_cpu.cpp:117] data. DefaultCPUAllocator: not enough memory: you tried "
                          "to allocate 1099511627776 bytes."),
    ],
)  # fmt: skip
def test_out_of_memory_in_a_plugin_names_the_stage(sim: str, cause: str, site: Path, tmp_path: Path, capsys) -> None:
    assert _run(tmp_path, sim) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"error: out of memory ({cause}) (stage: fit of simulator '{sim}', seed 0); {MEMORY}"
    assert not list((tmp_path / "runs").glob("clods-bench-traceback-*"))  # the machine's failure, no bug: no traceback file


def test_a_builtin_plugin_that_raises_is_a_bug_to_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def broken(self: ConstantVelocity, inp: object) -> None:
        raise IndexError("index 24 is out of bounds for axis 0 with size 24")

    monkeypatch.setattr(ConstantVelocity, "rollout", broken)
    assert _run(tmp_path, "constvel") == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    saved = _traceback_file(line)
    assert line == (
        "internal error: simulator 'constvel' raised IndexError during rollout (stage: rollout, seed 0): index 24 is out of bounds for "
        f"axis 0 with size 24 (a bug in clods-bench; please report it at the clods-bench issue tracker with the traceback saved in {saved})"
    )
    assert "IndexError: index 24 is out of bounds" in saved.read_text() and "in broken" in saved.read_text()


def test_a_bug_outside_plugins_is_an_internal_error_with_its_traceback_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise KeyError("max_strain")

    monkeypatch.setattr("clods_bench.benchmark.running.runner.aggregate", broken)
    assert _run(tmp_path, "constvel") == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    saved = _traceback_file(line)
    assert line == ("internal error: KeyError: 'max_strain' (a bug in clods-bench; please report it at the clods-bench issue tracker "
                    f"with the traceback saved in {saved})")  # fmt: skip
    assert saved.parent == (tmp_path / "runs").resolve() and saved.read_text().startswith("clods-bench run cdg --sim constvel")


def test_permission_denied_names_the_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    replace = os.replace

    def denied(src: str, dst: str) -> None:
        if Path(dst).name == records.RECORD_FILE:
            raise PermissionError(errno.EACCES, "Permission denied", str(dst))
        replace(src, dst)

    monkeypatch.setattr(atomic.os, "replace", denied)
    assert _run(tmp_path, "constvel") == 2
    record = next((tmp_path / "runs").rglob("seed_0")).parent / records.RECORD_FILE
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: permission denied: {record}; make it writable or point runs_dir / data.root elsewhere"
    )


def test_a_plugin_error_crosses_a_process_boundary_whole() -> None:
    """A seed run in a worker process raises there; the driver prints the same line (the exception is pickled)."""
    err = PluginError("simulator", "raise-sim", "rollout", "ValueError", "bad mesh", seed=1, builtin=False)
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is PluginError and back.message == err.message == (
        "simulator 'raise-sim' raised ValueError during rollout (stage: rollout, seed 1): bad mesh"
    )
    assert (back.kind, back.name, back.stage, back.seed, back.builtin) == ("simulator", "raise-sim", "rollout", 1, False)
    full = pickle.loads(pickle.dumps(OSError(errno.ENOSPC, "No space left on device", "/data/traj_0001.npz")))
    assert (full.errno, full.filename) == (errno.ENOSPC, "/data/traj_0001.npz")
