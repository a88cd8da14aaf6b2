"""Every bad config value is refused before any work: one line naming its field, exit 2, and no dataset or record
folder created (in `run`, `reproduce` and `reproduce --dry-run`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from clods_bench.cli import main
from clods_bench.datasets import data_checks
from clods_bench.typed_config import MAX_STEPS
from tests.conftest import TINY

SIMS = "bsms, constvel, dhmp, frozen, hcmt, lip, mgn, physics"

BAD = [
    ("sim_config.mgn.learning_rate=-1", "sim_config.mgn.learning_rate: must be a finite number > 0, got -1.0"),
    ("sim_config.mgn.learning_rate=.nan", "sim_config.mgn.learning_rate: must be a finite number > 0, got nan"),
    ("sim_config.mgn.train_steps=0", "sim_config.mgn.train_steps: must be an integer >= 1, got 0"),
    ("sim_config.mgn.train_steps=100000000000000000",
     "sim_config.mgn.train_steps: must be <= 100000000 (10^8, the largest step count clods-bench accepts), got 100000000000000000"),
    ("sim_config.mgn.noise_std=.inf", "sim_config.mgn.noise_std: must be a finite number >= 0, got inf"),
    ("sim_config.mgn.noise_gamma=.nan", "sim_config.mgn.noise_gamma: must be a finite number >= 0, got nan"),
    ("seeds=[-1]", "seeds[0]: must be an integer in [0, 4294967295], got -1"),
    ("seeds=[]", "seeds: is empty: a run needs at least one seed (e.g. --set seeds=[0])"),
    ("seeds=[0, 0]", "seeds: lists seed(s) [0] more than once"),
    ("sim_config.nosuchsim.foo=1", f"sim_config.nosuchsim: unknown simulator 'nosuchsim'; known: {SIMS}"),
    ("sim_config.mgm.latent_size=8", f"sim_config.mgm: unknown simulator 'mgm'; known: {SIMS} (did you mean 'mgn'?)"),
    ("video_config.simpv.train_steps=8", "video_config.simpv: unknown video_predictor 'simpv'; known: copylast, mau, mmvp, simvp, tau "
                                         "(did you mean 'simvp'?)"),
    ("data.num_steps=0", "data.num_steps: must be an integer >= 4, got 0"),
    ("data.num_steps=1000000000", "data.num_steps: must be <= 100000000 (10^8, the largest step count clods-bench accepts), got 1000000000"),
    ("data.fov_deg=.nan", "data.fov_deg: must be a finite number > 0 and <= 179, got nan"),
    ("data.seed=-3", "data.seed: must be an integer >= 0, got -3"),
    ("data.image_size=0", "data.image_size: must be an integer >= 1, got 0"),
    ("renderer_config.smgs.iterations=-1", "renderer_config.smgs.iterations: must be an integer >= 0, got -1"),
    ("task_config.stability.horizon_factor=.inf", "task_config.stability.horizon_factor: must be a finite number, got inf"),
]  # fmt: skip


def _args(root: Path, *sets: str) -> list[str]:
    """`--set` options of the tiny config writing under `root`, then `sets`."""
    return [a for s in (*TINY, f"data.root={root / 'data'}", f"runs_dir={root / 'runs'}", *sets) for a in ("--set", s)]


def _nothing_created(root: Path) -> bool:
    return not any(root.iterdir())


@pytest.mark.parametrize(("override", "line"), BAD, ids=[b[0] for b in BAD])
def test_run_refuses_a_bad_value_before_any_work(override: str, line: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    task = ["run", "cdg", "--sim", "mgn", "--renderer", "smgs"] if override.startswith("renderer_config") else ["run", "cdg", "--sim", "mgn"]
    assert main([*task, *_args(tmp_path, override)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {line}"
    assert _nothing_created(tmp_path)  # no dataset folder, no record folder, no traceback file


def test_seeds_on_the_command_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    sets = [s for s in TINY if not s.startswith("seeds=")]  # the tiny config's --set seeds would win over --seeds
    args = [a for s in (*sets, f"data.root={tmp_path / 'data'}", f"runs_dir={tmp_path / 'runs'}") for a in ("--set", s)]
    assert main(["run", "cdg", "--sim", "constvel", *args, "--seeds", "3", "-1"]) == 2
    assert capsys.readouterr().err.strip() == "error: seeds[1]: must be an integer in [0, 4294967295], got -1"
    assert _nothing_created(tmp_path)


def test_a_dataset_larger_than_memory_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """A dataset whose arrays cannot fit is refused with what it needs and what there is: the machine's real memory
    (10^8 steps of a 100 x 100 flag: 32.7 TiB), and an exact line against a given available size."""
    monkeypatch.chdir(tmp_path)
    assert main(["run", "cdg", "--sim", "constvel", *_args(tmp_path, "data.resolution=[100,100]", f"data.num_steps={MAX_STEPS}")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: data: the dataset needs 32.7 TiB for its world_pos of 3 trajectories x 100000000 steps x 10000 nodes, "
                          "float32; ") and err.endswith(" of memory is available (lower data.num_steps, data.resolution, "
                                                        "data.num_train/num_test or data.image_size)")  # fmt: skip
    assert _nothing_created(tmp_path)

    monkeypatch.setattr(data_checks, "available_memory", lambda: 512 << 20)
    assert main(["run", "cdg", "--sim", "constvel", *_args(tmp_path, "data.num_steps=1000000")]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: data: the dataset needs 824 MiB for its world_pos of 3 trajectories x 1000000 steps x 24 nodes, float32; 512 MiB of "
        "memory is available (lower data.num_steps, data.resolution, data.num_train/num_test or data.image_size)"
    )  # fmt: skip
    assert _nothing_created(tmp_path)
    assert main(["run", "cdg", "--sim", "constvel", *_args(tmp_path, "data.image_size=2048", "data.supersample=4")]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: data: the dataset needs 6 GiB for its one time step rendered by 3 cameras at 8192x8192 px (colour and depth, float64); "
        "512 MiB of memory is available (lower data.num_steps, data.resolution, data.num_train/num_test or data.image_size)"
    )  # fmt: skip
    assert _nothing_created(tmp_path)


@pytest.mark.parametrize("dry_run", [True, False], ids=["dry-run", "reproduce"])
def test_reproduce_refuses_a_bad_value_in_one_line(dry_run: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """A bad override shared by many rows of the plan is one line naming the field and the rows it breaks."""
    monkeypatch.chdir(tmp_path)
    argv = ["reproduce", "--only", "table2_cdg", "--first-seeds", "1", "--out", str(tmp_path / "out"), *_args(tmp_path, "sim_config.mgn.learning_rate=.nan")]
    assert main([*argv, *(["--dry-run"] if dry_run else [])]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: sim_config.mgn.learning_rate: must be a finite number > 0, got nan "
        "(6 rows: table2_cdg/MGN, table2_cdg/MGN*, table2_cdg/CloDS* and 3 more)"
    )
    assert _nothing_created(tmp_path)
    assert main(["reproduce", "--only", "table2_cdg", "--dry-run", *_args(tmp_path, "seeds=[]")]) == 2
    assert capsys.readouterr().err.strip().startswith("error: seeds: is empty: a run needs at least one seed (e.g. --set seeds=[0]) (12 rows: ")
    assert _nothing_created(tmp_path)
