"""OBJ/PLY export of a run's mesh samples: positions and faces come back from the files, bad samples are refused."""

from __future__ import annotations

import numpy as np
import pytest

from clods_bench.benchmark.outputs.mesh_export import export_mesh_sample, folder_name
from clods_bench.benchmark.outputs.mesh_pictures import save_mesh_sample
from clods_bench.cli import main
from clods_bench.datasets.mesh_io import read_triangle_mesh
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.errors import ClodsError


def _sample(tmp_path, bad: bool = False):
    flag = make_flag_mesh(4, 3, 1.0, 0.5)
    rng = np.random.default_rng(0)
    truth = flag.rest_pos[None] + rng.normal(scale=0.01, size=(3, flag.num_nodes, 3))
    pred = truth + 0.02
    if bad:
        pred[2, 1, 0] = np.nan
    path = save_mesh_sample(tmp_path / "rollout_meshes.npz", flag.cells, {"MGN (pred)": pred}, truth=truth, title="t")
    return path, flag, truth.astype(np.float32), pred.astype(np.float32)


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_every_sequence_comes_back_from_its_files(tmp_path, fmt):
    path, flag, truth, pred = _sample(tmp_path)
    written = export_mesh_sample(path, tmp_path / "out", fmt)
    assert sorted(written) == ["MGN (pred)", "truth"]
    for name, frames in (("MGN (pred)", pred), ("truth", truth)):
        files = written[name]
        assert [f.name for f in files] == [f"frame_{t:04d}.{fmt}" for t in range(3)]
        assert files[0].parent.name == folder_name(name)
        for t, f in enumerate(files):
            verts, faces, _ = read_triangle_mesh(f)
            np.testing.assert_allclose(verts, frames[t], atol=1e-6)
            np.testing.assert_array_equal(faces, flag.cells)


def test_folder_names_are_safe():
    assert folder_name("extracted (stage 2)") == "extracted_stage_2"
    assert folder_name("CloDS** / MGN") == "CloDS_MGN"


def test_bad_samples_are_refused(tmp_path):
    with pytest.raises(ClodsError, match="no such mesh sample"):
        export_mesh_sample(tmp_path / "missing.npz", tmp_path / "out")
    path, *_ = _sample(tmp_path, bad=True)
    with pytest.raises(ClodsError, match="'MGN \\(pred\\)' has non-finite positions at frame 2"):
        export_mesh_sample(path, tmp_path / "out")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ClodsError, match="not a mesh sample"):
        export_mesh_sample(tmp_path / "junk.npz", tmp_path / "out")


def test_the_command_writes_the_files(tmp_path):
    path, *_ = _sample(tmp_path)
    assert main(["data", "export-meshes", str(path), "--format", "ply", "--out", str(tmp_path / "cli")]) == 0
    assert len(list((tmp_path / "cli" / "truth").glob("*.ply"))) == 3
    assert main(["data", "export-meshes", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "x")]) == 2
