"""start=simulator (the Cloth-Splatting-style predict step): the start guess is the simulator's own one-step rollout,
frame 1 starts as before, the extraction cache key names the pretrained fit, and the option needs variant=finetune."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.extract import start_guess
from clods_bench.benchmark.clods.pipeline import extraction_identity
from clods_bench.benchmark.clods.predict import OneStepPredictor
from clods_bench.benchmark.core.cache_keys import digest
from clods_bench.benchmark.core.interfaces import RolloutInput
from clods_bench.datasets.types import NORMAL
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.baselines import ConstantVelocity

from .conftest import grid

SIM = ClodsConfig(variant="finetune", start="simulator")


def _meshes(k: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """k moving float32 meshes of the test grid (handles fixed at the first mesh), with its cells, mesh_pos, node types."""
    verts, cells, mesh_pos, node_type = grid()
    free = node_type == NORMAL
    rng = np.random.default_rng(seed)
    done = np.repeat(verts[None], k, axis=0)
    done[:, free] += rng.normal(0.0, 0.05, (k, int(free.sum()), 3)).astype(np.float32)
    return done.astype(np.float32), cells, mesh_pos, node_type


def test_constant_velocity_predictor_gives_the_velocity_start_bit_for_bit():
    """constvel's one step, x_t + (x_t - x_{t-1}), is exactly what start=velocity extrapolates."""
    done, cells, mesh_pos, nt = _meshes()
    free = nt == NORMAL
    predict = OneStepPredictor(ConstantVelocity(), cells, mesh_pos, nt, 0.02, "constvel")
    by_sim = start_guess(done, SIM, free, predict)
    by_velocity = start_guess(done, ClodsConfig(start="velocity"), free)
    assert by_sim.dtype == by_velocity.dtype == np.float32
    np.testing.assert_array_equal(by_sim, by_velocity)
    hand = (2.0 * done[-1].astype(np.float64) - done[-2])[free]  # and both are the hand formula, to float32 rounding
    np.testing.assert_allclose(by_sim[free], hand, rtol=0, atol=1e-6)
    assert np.abs(by_sim[free] - done[-1][free]).max() > 0.01  # it did move: not the 'previous' start


class Recorder:
    """A simulator whose step returns a fixed mesh at the free nodes (the kinematic ones as given: the rollout
    contract); it records the input it was given."""

    def __init__(self, answer: np.ndarray) -> None:
        self.answer = answer
        self.inputs: list[RolloutInput] = []

    def fit(self, train, ctx):  # pragma: no cover - never trained here
        return {}

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        self.inputs.append(inp)
        out = np.zeros((inp.num_frames, *self.answer.shape), np.float32)
        out[:2] = inp.init_pos
        out[2:] = self.answer
        out[2:, inp.kinematic_mask] = inp.kinematic_pos[2:, inp.kinematic_mask]
        return out


def test_predict_step_rolls_the_simulator_one_step_from_the_last_two_meshes():
    done, cells, mesh_pos, nt = _meshes(k=4)
    free = nt == NORMAL
    answer = (done[-1] + np.float32(0.125)).astype(np.float32)
    sim = Recorder(answer)
    got = start_guess(done, SIM, free, OneStepPredictor(sim, cells, mesh_pos, nt, 0.02))
    (inp,) = sim.inputs
    np.testing.assert_array_equal(inp.init_pos, done[-2:])  # frames t-1 and t, in that order
    assert inp.num_frames == 3 and inp.dt == 0.02
    assert np.isnan(inp.kinematic_pos[:, free]).all()  # free nodes are not given away
    np.testing.assert_array_equal(inp.kinematic_pos[:, ~free], np.repeat(done[-1][None, ~free], 3, axis=0))
    np.testing.assert_array_equal(got[free], answer[free])  # the simulator's step, as it returned it
    np.testing.assert_array_equal(got[~free], done[-1][~free])  # handles stay where the last mesh has them


def test_frame_one_starts_from_the_initial_mesh_without_a_prediction():
    done, cells, mesh_pos, nt = _meshes(k=1)
    sim = Recorder(done[0] + 1.0)
    got = start_guess(done, SIM, nt == NORMAL, OneStepPredictor(sim, cells, mesh_pos, nt, 0.02))
    np.testing.assert_array_equal(got, done[0])
    assert sim.inputs == []


def test_a_non_finite_prediction_and_a_missing_predictor_are_clear_errors():
    done, cells, mesh_pos, nt = _meshes()
    bad = np.full_like(done[-1], np.nan)
    with pytest.raises(ClodsError, match="not finite") as err:
        start_guess(done, SIM, nt == NORMAL, OneStepPredictor(Recorder(bad), cells, mesh_pos, nt, 0.02))
    assert err.value.where == "task_config.clods.start"
    with pytest.raises(ClodsError, match="predict step") as err:
        start_guess(done, SIM, nt == NORMAL, None)
    assert err.value.where == "task_config.clods.start"


@pytest.mark.parametrize("variant", ["scratch"])
def test_start_simulator_needs_the_finetune_variant(variant):
    with pytest.raises(ClodsError, match="variant=finetune") as err:
        ClodsConfig(variant=variant, start="simulator").validate()
    assert err.value.where == "task_config.clods.start"
    ClodsConfig(variant="finetune", start="simulator").validate()  # the CS row's setting is accepted


def test_start_simulator_error_through_the_run_config():
    from clods_bench.benchmark.clods.config import clods_config
    from clods_bench.benchmark.core.config import RunConfig

    cfg = dataclasses.replace(RunConfig(), task_config={"clods": {"start": "simulator"}})
    with pytest.raises(ClodsError) as err:
        clods_config(cfg)
    assert err.value.where == "task_config.clods.start"
    ok = dataclasses.replace(RunConfig(), task_config={"clods": {"start": "simulator", "variant": "finetune"}})
    assert clods_config(ok).start == "simulator"


# Digests of the same identities computed with the code on main before start=simulator existed
# (stage1 'abc123', data {'scene': 'flag', 'seed': 0}, 31 frames, views 0-3).
MAIN_DIGESTS = {
    "default": ("2e6d9c95ba00125b", ClodsConfig()),
    "ci previous": ("2701b0dc5b8a5267", ClodsConfig(start="previous", iterations=15, min_iterations=5, patience=4, extraction_seed=0)),
}


def _key(opts: ClodsConfig, predictor: dict | None = None) -> str:
    return digest(extraction_identity("abc123", opts, {"scene": "flag", "seed": 0}, 31, [0, 1, 2, 3], predictor))


@pytest.mark.parametrize("name", sorted(MAIN_DIGESTS))
def test_existing_starts_keep_their_cache_key(name):
    expected, opts = MAIN_DIGESTS[name]
    assert _key(opts) == expected
    assert _key(opts, {"sim": "mgn", "seed": 0}) == expected  # a predictor identity is ignored unless start=simulator


def test_start_simulator_key_names_the_pretrained_fit():
    fit0, fit1 = {"sim": "mgn", "seed": 0, "train_ids": [0, 1]}, {"sim": "mgn", "seed": 1, "train_ids": [0, 1]}
    keys = {_key(SIM, fit0), _key(SIM, fit1), _key(dataclasses.replace(SIM, start="velocity"))}
    assert len(keys) == 3  # another pretrained fit, or no predictor, is another extraction
    assert _key(SIM, dict(fit0)) == _key(SIM, fit0)  # deterministic
    with pytest.raises(ClodsError) as err:
        _key(SIM, None)
    assert err.value.where == "task_config.clods.start"


def test_stop_requires_progress_is_part_of_the_cache_key_only_when_set():
    assert _key(ClodsConfig(stop_requires_progress=False)) == MAIN_DIGESTS["default"][0]
    assert _key(ClodsConfig(stop_requires_progress=True)) != MAIN_DIGESTS["default"][0]
