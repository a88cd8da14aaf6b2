"""One flipped bit in each artefact a later step trusts is one error line naming the file and what to do (exit 2),
never a silent reuse; doing what it says recovers the same numbers and stage digests."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.core.resolve import resolve_plugins
from clods_bench.benchmark.running.records import RECORD_FILE, read_record, record_dir, seed_result_path
from clods_bench.benchmark.running.runner import run_data_digests
from clods_bench.datasets.generate import generate
from tests.conftest import tiny_config
from tests.reliability.integrity_helpers import cli, error_line, flip_bit, flip_digit_of, tiny_args

KEY = "viewed/interp/d_avg"
CHANGED = "content differs from the SHA-256 written with it: the file was changed or damaged after it was written"
MGN = ["sim_config.mgn.train_steps=15", "sim_config.mgn.latent_size=16", "sim_config.mgn.message_passing_steps=2",
       "sim_config.mgn.warmup_steps=2"]  # fmt: skip
SIMVP = ["task_config.dvc.lpips=false", "video_config.simvp.context_frames=3", "video_config.simvp.hid_s=8",
         "video_config.simvp.hid_t=16", "video_config.simvp.enc_layers=2", "video_config.simvp.trans_layers=2",
         "video_config.simvp.kernels=[3]", "video_config.simvp.groups=2", "video_config.simvp.train_steps=6",
         "video_config.simvp.batch_size=4", "video_config.simvp.num_threads=1"]  # fmt: skip


def _seed(rdir: Path, seed: int = 0) -> dict:
    """What must come back after a remedy: a seed's metrics and its stage digests (data, fit, rollout, score)."""
    done = json.loads(seed_result_path(rdir, seed).read_text())
    return {"metrics": done["metrics"], "stages": done["extra"]["stage_digests"], "data": done["data_digests"]}


def _rdir(root: Path, runs: Path, *extra: str, **fields: str) -> Path:
    reg = default_registry()
    return record_dir(resolve_plugins(tiny_config(root, f"runs_dir={runs}", *extra, **fields), reg), reg)


def test_a_flipped_record_mean_is_named_by_tables_and_rebuilt_by_a_run(tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    args = ["run", "cdg", "--sim", "constvel", "--jobs", "1", *tiny_args(tiny_root, runs, "seeds=[0, 1]")]
    assert cli(capsys, *args)[0] == 0
    rdir = _rdir(tiny_root, runs, sim="constvel")
    good = read_record(rdir / RECORD_FILE)
    old, new = flip_digit_of(rdir / RECORD_FILE, ["metrics", KEY, "mean"])
    assert abs(new - old) < 0.5 * abs(old)  # the user's case: a plausible number, 0.1282 -> 0.1382
    tables = ["tables", "--runs", str(runs), "--out", str(tmp_path / "tables")]
    line = error_line(capsys, *tables)
    remedy = f"clods-bench run cdg --config {rdir / 'config.yaml'}"
    assert line == f"error: {rdir / RECORD_FILE}: {CHANGED} (rebuild it from its seed results: {remedy})"
    assert cli(capsys, *remedy.split()[1:])[0] == 0  # the remedy, as the message spells it
    fixed = read_record(rdir / RECORD_FILE)
    assert fixed["seeds"] == [0, 1] and fixed["metrics"] == good["metrics"] and fixed["per_seed"] == good["per_seed"]
    assert cli(capsys, *tables)[0] == 0


def test_a_flipped_result_metric_is_named_and_the_seed_reruns_to_the_same_digests(
    tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:  # fmt: skip
    runs = tmp_path / "runs"
    args = ["run", "cdg", "--sim", "constvel", *tiny_args(tiny_root, runs)]
    assert cli(capsys, *args)[0] == 0
    rdir = _rdir(tiny_root, runs, sim="constvel")
    good = _seed(rdir)
    flip_digit_of(seed_result_path(rdir, 0), ["metrics", KEY])
    line = error_line(capsys, *args)  # never "finished earlier"
    assert line == f"error: {seed_result_path(rdir, 0)}: {CHANGED} (delete {rdir / 'seed_0'} to run seed 0 again)"
    shutil.rmtree(rdir / "seed_0")
    assert cli(capsys, *args)[0] == 0
    assert _seed(rdir) == good


def test_a_flipped_bit_in_a_cached_fits_weights_is_named_and_the_fit_retrains_to_the_same_digests(
    tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:  # fmt: skip
    runs = tmp_path / "runs"
    args = ["run", "cdg", "--sim", "mgn", *tiny_args(tiny_root, runs, *MGN)]
    assert cli(capsys, *args)[0] == 0
    rdir = _rdir(tiny_root, runs, *MGN, sim="mgn")
    good = _seed(rdir)
    (weights,) = (runs / "fit_cache").glob("mgn-*/mgn.ckpt")
    flip_bit(weights, weights.stat().st_size // 2)
    shutil.rmtree(rdir / "seed_0")  # the seed runs again and reads the cached fit
    line = error_line(capsys, *args)
    assert line == f"error: {weights}: {CHANGED} (delete it to train from scratch (or use another work directory))"
    weights.unlink()
    assert cli(capsys, *args)[0] == 0
    assert _seed(rdir) == good


def test_a_flipped_bit_in_a_predictor_checkpoint_is_named_and_it_retrains_to_the_same_digests(
    tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:  # fmt: skip
    runs = tmp_path / "runs"
    args = ["run", "dvc", "--predictor", "simvp", *tiny_args(tiny_root, runs, *SIMVP)]
    assert cli(capsys, *args)[0] == 0
    rdir = _rdir(tiny_root, runs, *SIMVP, task="dvc", predictor="simvp")
    good = _seed(rdir)
    (checkpoint,) = (runs / "fit_cache").glob("simvp-*/simvp.pt")
    flip_bit(checkpoint, 100, bit=3)
    shutil.rmtree(rdir / "seed_0")
    line = error_line(capsys, *args)
    assert line == f"error: {checkpoint}: {CHANGED} (delete it to train from scratch (or use another work directory))"
    checkpoint.unlink()
    assert cli(capsys, *args)[0] == 0
    assert _seed(rdir) == good


def test_a_changed_dataset_array_is_named_even_when_every_seed_is_reused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The user's case: one value moved 1 cm and the file rewritten; and a one-bit flip. The kept content digest is not
    trusted over the arrays: the run stops naming the file, and regenerating gives the same digests back."""
    cfg = tiny_config(tmp_path)
    generate(cfg.data, default_registry().get("scene", cfg.data.scene), progress=False)
    args = ["run", "cdg", "--sim", "constvel", *tiny_args(tmp_path, tmp_path / "runs")]
    assert cli(capsys, *args)[0] == 0
    rdir = _rdir(tmp_path, tmp_path / "runs", sim="constvel")
    good, digests = _seed(rdir), run_data_digests(cfg, default_registry())
    root = cfg.data.dataset_dir()
    path = root / "traj_0001.npz"
    with np.load(path) as npz:
        arrays = dict(npz)
    arrays["world_pos"][5, 3, 0] += 0.01
    np.savez_compressed(path, **arrays)
    line = error_line(capsys, *args)
    assert line.startswith(f"error: {path}: ")
    assert line.endswith(f"(delete {root} and run again, which regenerates it (or: clods-bench data generate --force with the run's settings))")
    shutil.rmtree(root)  # the remedy
    assert cli(capsys, *args)[0] == 0
    assert _seed(rdir) == good and run_data_digests(cfg, default_registry()) == digests
    flip_bit(root / "traj_0002.npz", 200)  # a one-bit flip, same size
    line = error_line(capsys, *args)
    assert line == (f"error: {root / 'traj_0002.npz'}: content differs from the SHA-256 the dataset's manifest records for it: "
                    f"the file was changed or damaged after it was written (delete {root} and run again, which regenerates it "
                    f"(or: clods-bench data generate --force with the run's settings))")  # fmt: skip
    assert cli(capsys, "data", "generate", "--force", "--no-progress", *tiny_args(tmp_path, tmp_path / "runs"))[0] == 0
    assert cli(capsys, *args)[0] == 0
    assert _seed(rdir) == good and run_data_digests(cfg, default_registry()) == digests
