"""BSMS's and DHMP's fibre options against brute force: the norms, the position scales and the twice-run mesh level.

Each GMP's fibres are captured with a forward pre-hook on its edge MLP and compared with numpy's own differences,
norms, means and standard deviations of the positions the test built.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.bsms import BsmsProcessor, build_bsms
from clods_bench.plugins.simulators.learned.dhmp import DhmpProcessor
from clods_bench.plugins.simulators.learned.graph import build_topology
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig, DhmpConfig
from clods_bench.datasets.meshes import make_flag_mesh
from tests.plugins.simulators.graph_fixtures import jittered_mesh, make_inputs
from tests.plugins.simulators.structure_fixtures import CI_WIDTHS, PINNED, assert_close, fixed_evaluation, mlp_parameters, shared_parameters

LATENT = 16


def captured_fibres(module: torch.nn.Module) -> tuple[list[torch.Tensor], list[torch.utils.hooks.RemovableHandle]]:
    """The fibre argument of every call of every edge MLP below `module`, in call order."""
    seen: list[torch.Tensor] = []
    handles = [m.register_forward_pre_hook(lambda _m, args: seen.append(args[1].detach().clone()))
               for name, m in module.named_modules() if name.endswith(".edge")]  # fmt: skip
    return seen, handles


def brute_fibres(pos: np.ndarray, s: np.ndarray, r: np.ndarray, groups: list[tuple[int, int]]) -> np.ndarray:
    d = pos[s] - pos[r]
    return np.concatenate([d, *[np.linalg.norm(d[:, a:b], axis=1, keepdims=True) for a, b in groups]], axis=1)


def bsms(**options: object) -> BsmsProcessor:
    torch.manual_seed(0)
    return BsmsProcessor(LATENT, 1, ["mesh"], BsmsConfig(latent_size=LATENT, levels=1, **options)).double()


def test_separate_norms_are_the_rest_and_the_world_difference_norms():
    s, r, mp = jittered_mesh(6, 5, seed=0)
    nodes, inputs = make_inputs(s, r, mp, LATENT, seed=0, key="a", dtype=torch.float64)
    proc = bsms(position_scale="raw", fibre_norms="separate")
    seen, handles = captured_fibres(proc)
    proc(nodes, inputs)
    pos = np.concatenate([mp, inputs.pos.numpy()], axis=1)
    np.testing.assert_allclose(seen[0].numpy(), brute_fibres(pos, s, r, [(0, 2), (2, 5)]), rtol=1e-12, atol=1e-15)
    joint = bsms(position_scale="raw", fibre_norms="joint")
    seen, handles = captured_fibres(joint)
    joint(nodes, inputs)
    np.testing.assert_allclose(seen[0].numpy(), brute_fibres(pos, s, r, [(0, 5)]), rtol=1e-12, atol=1e-15)


def test_level_scale_normalises_each_levels_fibres_by_their_own_statistics():
    """After one accumulating call, level 0's fibres are (raw - mean) / std of level 0's raw fibres, and the bottom
    level's by the bottom's: every fibre column has mean 0 and std 1 where it varies."""
    s, r, mp = jittered_mesh(7, 6, seed=1)
    nodes, inputs = make_inputs(s, r, mp, LATENT, seed=1, key="a", dtype=torch.float64)
    inputs = inputs.__class__(**{**inputs.__dict__, "accumulate": True})
    proc = bsms(position_scale="level", fibre_norms="separate")
    seen, _ = captured_fibres(proc)
    proc(nodes, inputs)
    pos = np.concatenate([mp, inputs.pos.numpy()], axis=1)
    raw = brute_fibres(pos, s, r, [(0, 2), (2, 5)])
    expected = (raw - raw.mean(0)) / raw.std(0)
    np.testing.assert_allclose(seen[0].numpy(), expected, rtol=1e-5, atol=1e-6)  # the normaliser's float32 statistics
    bottom = seen[1].numpy()  # down 0, bottom, up 0: the bottom level's fibres are standardised too
    np.testing.assert_allclose(bottom.mean(0), 0.0, atol=1e-5)
    np.testing.assert_allclose(bottom.std(0), 1.0, rtol=1e-4)
    torch.testing.assert_close(seen[2], seen[0], rtol=0, atol=0)  # the way up reads level 0's fibres again


def test_dataset_scale_hands_the_processor_positions_normalised_per_coordinate():
    """LearnedModel's position normaliser: each of the 2 rest and 3 world coordinates minus its mean over the
    accumulated nodes, over its std; the BSMS fibres are built from those."""
    mesh = make_flag_mesh(8, 5)
    sim = build_bsms(BsmsConfig(latent_size=LATENT, hidden_layers=1, levels=1, position_scale="dataset", fibre_norms="separate"),
                     SimpleNamespace(scene=PINNED))  # fmt: skip
    model = sim.build_model(0).double()
    topo = build_topology(mesh.cells, mesh.mesh_pos, mesh.node_type)
    mp = mesh.mesh_pos.astype(np.float64)
    world = np.stack([mp[:, 0], 0.2 * np.sin(mp[:, 0] * 3.0), mp[:, 1] * 0.9], axis=1)
    seen, _ = captured_fibres(model.processor)
    x = torch.as_tensor(world)
    model(topo, "k", x, x - 0.01, accumulate=True)
    both = np.concatenate([mp, world], axis=1)
    normalised = (both - both.mean(0)) / both.std(0)
    s, r = topo.senders.numpy(), topo.receivers.numpy()
    np.testing.assert_allclose(seen[0].numpy(), brute_fibres(normalised, s, r, [(0, 2), (2, 5)]), rtol=1e-5, atol=1e-6)
    assert model.position_normalizer is not None
    plain = build_bsms(BsmsConfig(latent_size=LATENT, hidden_layers=1, levels=1), SimpleNamespace(scene=PINNED)).build_model(0)
    assert plain.position_normalizer is None  # only a processor that reads normalised positions gets the normaliser


def test_repeat_mesh_level_runs_the_mesh_and_bottom_gmps_twice():
    s, r, mp = jittered_mesh(6, 5, seed=2)
    nodes, inputs = make_inputs(s, r, mp, LATENT, seed=2, key="a", dtype=torch.float64)
    counts = {}
    for repeat in (False, True):
        proc = bsms(position_scale="raw", repeat_mesh_level=repeat)
        seen, _ = captured_fibres(proc)
        proc(nodes, inputs)
        counts[repeat] = len(seen)
    assert counts == {False: 3, True: 6}  # down 0, bottom, up 0 (levels = 1): each twice


def test_dhmp_level_scale_standardises_its_mesh_level_fibres():
    s, r, mp = jittered_mesh(7, 6, seed=3)
    nodes, inputs = make_inputs(s, r, mp, LATENT, seed=3, key="a", dtype=torch.float64)
    inputs = inputs.__class__(**{**inputs.__dict__, "accumulate": True})
    torch.manual_seed(0)
    proc = DhmpProcessor(LATENT, 1, ["mesh"], DhmpConfig(latent_size=LATENT, levels=1, fixed_levels=1, position_scale="level")).double()
    seen, _ = captured_fibres(proc)
    proc(nodes, inputs)
    level0 = seen[0].numpy()  # the mesh level with self loops (zero fibres) is one column set
    np.testing.assert_allclose(level0.mean(0), 0.0, atol=1e-5)
    np.testing.assert_allclose(level0.std(0), 1.0, rtol=1e-4)


@pytest.mark.parametrize("field,value", [("position_scale", "metres"), ("fibre_norms", "both"), ("repeat_mesh_level", "yes"), ("output", "position")])
def test_bad_options_name_the_field(field, value):
    with pytest.raises(ClodsError, match=field):
        BsmsConfig(**{field: value}).validate()


def test_default_structure_at_ci_widths_is_pinned():
    """The default BSMS (separate norms: 7-wide fibres, level normalisers hold no parameters) by formula, and one
    fixed-seed float64 output (committed)."""
    count, value = fixed_evaluation(build_bsms(BsmsConfig(**CI_WIDTHS, levels=3), SimpleNamespace(scene=PINNED)))
    gmp = mlp_parameters(7 + 2 * 64, 64, 2, 64, False) + mlp_parameters(2 * 64, 64, 2, 64, False)
    assert count == shared_parameters(64, 2, encoded_edges=False) + (2 * 3 + 1) * gmp
    assert_close(value, PINNED_DEFAULT_BSMS)


PINNED_DEFAULT_BSMS = -49.45812477253863  # 2026-12-07, committed when the default became level-scaled separate norms
