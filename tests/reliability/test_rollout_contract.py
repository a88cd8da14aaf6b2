"""The rollout contract, enforced by `check_rollout`: numeric (T,V,3) output that returns the two given frames and
every kinematic node's given positions (within float32 rounding); every built-in simulator keeps it. A diverged
rollout's largest edge strain is reported as diverged, never as the strain of its finite frames."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.builders import build_simulator, fit_on_meshes
from clods_bench.benchmark.core.descriptors import PluginSpec, TaskContext
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.interfaces import CONTRACT_ULPS, ContractError, RolloutInput, check_rollout
from clods_bench.benchmark.core.registry import Registry, default_registry, make_plugin_manager
from clods_bench.benchmark.outputs.tables import write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.scoring.metrics import diverged_max, recorded_max
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import HANDLE, NORMAL, OBSTACLE
from clods_bench.plugins.simulators.baselines import ConstantVelocity
from tests.conftest import tiny_config

T, V = 6, 5
NODE_TYPE = np.array([HANDLE, NORMAL, NORMAL, NORMAL, OBSTACLE], np.int32)


def _input() -> RolloutInput:
    rng = np.random.default_rng(0)
    world = (rng.normal(size=(T, V, 3)) * 2.0).astype(np.float32)
    kin = world.copy()
    kin[:, NODE_TYPE == NORMAL] = np.nan
    return RolloutInput(np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4]], np.int32), np.zeros((V, 2), np.float32), NODE_TYPE, world[:2].copy(), kin, 0.02)


def _good(inp: RolloutInput) -> np.ndarray:
    out = np.repeat(inp.init_pos[1:2], T, axis=0).astype(np.float64)
    out[:2] = inp.init_pos
    out[2:, inp.kinematic_mask] = inp.kinematic_pos[2:, inp.kinematic_mask]
    return out


def _tolerance(inp: RolloutInput) -> float:
    return CONTRACT_ULPS * float(np.spacing(np.float32(np.nanmax(np.abs(inp.kinematic_pos)))))


def test_a_rollout_that_keeps_the_contract_passes_float64_and_divergence_included() -> None:
    inp = _input()
    out = check_rollout(_good(inp), inp, "s")  # float64 arithmetic on the float32 input: exact after the cast
    assert out.dtype == np.float32 and out.shape == (T, V, 3)
    diverged = _good(inp)
    diverged[4:] = np.nan  # NaN at any node from frame 2 on is a divergence: data, not a contract breach
    assert np.isnan(check_rollout(diverged, inp, "s")[4:]).all()
    handle = _good(inp)
    handle[3, 0] += (CONTRACT_ULPS - 1) * np.spacing(np.float32(np.abs(inp.kinematic_pos[3, 0]).max()))
    check_rollout(handle.astype(np.float32), inp, "s")  # within a few ulps: accepted


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda out, inp: np.zeros_like(out), "rollout changed given frame 0: node 0 (HANDLE)"),
        (lambda out, inp: out.__setitem__((1, 2), out[1, 2] + 1e-3) or out, "rollout changed given frame 1: node 2 (NORMAL)"),
        (lambda out, inp: out.__setitem__((4, 0, 1), out[4, 0, 1] + 1e-4) or out, "rollout moved kinematic node 0 (HANDLE) at frame 4"),
        (lambda out, inp: out.__setitem__((2, 4), 0.0) or out, "rollout moved kinematic node 4 (OBSTACLE) at frame 2"),
        (lambda out, inp: out.__setitem__((0, 3), np.nan) or out, "rollout changed given frame 0: node 3 (NORMAL) is (nan, nan, nan)"),
    ],
    ids=["zeros", "frame-1", "handle", "obstacle", "nan-in-frame-0"],
)
def test_changed_given_positions_are_named(edit, message: str) -> None:
    inp = _input()
    with pytest.raises(ContractError) as err:
        check_rollout(edit(_good(inp), inp), inp, "my-sim")
    assert err.value.where == "simulator 'my-sim'" and err.value.what.startswith(message)
    assert err.value.what.endswith(f"(tolerance {_tolerance(inp):.3g} m)")
    assert err.value.hint == "return frames 0 and 1 and every non-NORMAL node's kinematic_pos unchanged"


def test_a_few_ulps_more_is_refused() -> None:
    inp = _input()
    out = _good(inp)
    out[3, 0, 0] = inp.kinematic_pos[3, 0, 0] + 2 * _tolerance(inp)
    with pytest.raises(ContractError, match="rollout moved kinematic node 0 \\(HANDLE\\) at frame 3"):
        check_rollout(out, inp, "s")


@pytest.mark.parametrize(
    ("out", "what"),
    [
        (np.full((T, V, 3), None, dtype=object), "an array of dtype object"),
        (None, "NoneType"),
        ([[None] * 3] * V, "an array of dtype object"),
        ("frames", "str"),
        (np.ones((T, V, 3), bool), "an array of dtype bool"),
    ],
    ids=["object-array", "none", "list-of-none", "string", "bool"],
)
def test_non_numeric_output_is_one_error_without_a_numpy_warning(out: object, what: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any numpy RuntimeWarning fails the test
        with pytest.raises(ContractError) as err:
            check_rollout(out, _input(), "none-sim")
    assert err.value.message == f"simulator 'none-sim': rollout returned {what}, expected a (T,V,3) float32 array of positions"


def test_a_wrong_shape_is_named() -> None:
    with pytest.raises(ContractError) as err:
        check_rollout(np.zeros((T - 1, V, 3)), _input(), "s")
    assert err.value.message == f"simulator 's': rollout returned shape ({T - 1}, {V}, 3), expected ({T}, {V}, 3)"


SIM_OPTIONS = {"train_steps": 3, "warmup_steps": 1, "checkpoint_every": 3, "latent_size": 8, "batch_size": 1}


@pytest.fixture(scope="module")
def ball_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny dataset of a collision scene (a flag hit by a moving ball: OBSTACLE nodes after the cloth's)."""
    from clods_bench.datasets.generate import generate

    root = tmp_path_factory.mktemp("ball")
    cfg = tiny_config(root, "data.scene=flag-ball")
    generate(cfg.data, default_registry().get("scene", "flag-ball"), progress=False)
    return root


@pytest.mark.parametrize("scene", ["flag", "flag-ball"])
@pytest.mark.parametrize("sim", ["constvel", "frozen", "physics", "mgn", "bsms", "hcmt", "dhmp", "lip"])
def test_every_builtin_simulator_keeps_the_contract(sim: str, scene: str, tiny_root: Path, ball_root: Path, tmp_path: Path) -> None:
    """Fitted briefly on a tiny flag (handles) and on a flag hit by a ball (handles and obstacle nodes), each built-in
    simulator rolls out every stored trajectory within the contract."""
    reg = default_registry()
    learned = reg.get("simulator", sim).learned
    options = {**SIM_OPTIONS, **({"heads": 2} if sim == "hcmt" else {}), **({"levels": 1, "fixed_levels": 0} if sim == "dhmp" else {})}
    sets = [f"sim_config.{sim}.{k}={v}" for k, v in options.items()] if learned else []
    root = tiny_root if scene == "flag" else ball_root
    cfg = tiny_config(root, f"runs_dir={tmp_path}", f"data.scene={scene}", *sets, sim=sim)
    ctx = TaskContext(config=cfg, seed=0, work_dir=tmp_path, registry=reg)
    simulator = build_simulator(ctx)
    store = DatasetStore.open(cfg.data.dataset_dir())
    fit_on_meshes(ctx, simulator, store)
    for i in range(cfg.data.num_train + cfg.data.num_test):
        inp = RolloutInput.from_trajectory(store.load_trajectory(i))
        assert (inp.node_type == OBSTACLE).any() == (scene == "flag-ball")
        out = check_rollout(simulator.rollout(inp), inp, sim)
        assert out.shape == inp.kinematic_pos.shape


def test_diverged_max_and_its_record() -> None:
    assert diverged_max([0.1, 0.3, 0.2]) == 0.3
    assert diverged_max([0.1, np.nan, 0.017]) == np.inf  # not 0.1: the strain of the finite frames alone
    assert diverged_max([0.1, np.inf]) == np.inf and np.isnan(diverged_max([]))
    assert recorded_max(0.3) == 0.3 and np.isnan(recorded_max(np.inf))


class NaNFrom(ConstantVelocity):
    """Constant velocity, NaN at the free nodes from frame 5 on (its kinematic nodes kept): a diverged rollout."""

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        out = super().rollout(inp)
        out[5:, ~inp.kinematic_mask] = np.nan
        return out


class Diverging:
    @hookimpl
    def clods_bench_simulators(self) -> list[PluginSpec]:
        return [PluginSpec(name="nan-from", description="diverges at frame 5", build=lambda cfg, ctx: NaNFrom())]


def test_a_diverged_rollouts_strain_is_reported_as_diverged(tiny_root: Path, tmp_path: Path) -> None:
    """CDG and stability: the record holds no strain (null) for a run with a diverged rollout, and the tables print
    it as diverged, next to the stable constant-velocity row whose strain is a number."""
    reg = Registry.from_plugin_manager(make_plugin_manager(extra_plugins=[Diverging()]))
    runs = tmp_path / "runs"
    for task in ("cdg", "stability"):
        for sim in ("nan-from", "constvel"):
            rdir = run_task(tiny_config(tiny_root, f"runs_dir={runs}", sim=sim, task=task), reg)
            rec = json.loads((rdir / RECORD_FILE).read_text())
            strain = rec["metrics"]["max_strain"]
            if sim == "nan-from":
                assert strain == {"mean": None, "std": None} and rec["per_seed"]["0"]["metrics"]["max_strain"] is None
            else:
                assert strain["mean"] > 0
    write_tables(runs, tmp_path / "t", task="cdg")
    md = next((tmp_path / "t").glob("cdg_*.md")).read_text()
    row = next(line for line in md.splitlines() if line.startswith("| nan-from"))
    assert row.rstrip(" |").split("|")[-3].strip() == "diverged@5"  # the 'Stability / max edge strain' column
    write_tables(runs, tmp_path / "s", task="stability")
    md = next((tmp_path / "s").glob("stability*.md")).read_text()
    row = next(line for line in md.splitlines() if line.startswith("| nan-from"))
    assert "| n/a (diverged) " in row and row.count("n/a (diverged)") == 2  # RMSE and max edge strain
