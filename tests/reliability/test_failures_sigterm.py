"""SIGTERM to a computing command that runs in one process ends it like Ctrl-C: the 'interrupted' line, status 130,
finished work kept; the same command then resumes (here: a fit from its last checkpoint) to the numbers of a run
that was never stopped."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from clods_bench.cli import main
from tests.conftest import TINY
from tests.plugin_packages import ROOT

MGN = ["sim_config.mgn.train_steps=60", "sim_config.mgn.warmup_steps=2", "sim_config.mgn.checkpoint_every=5", "sim_config.mgn.latent_size=16"]


def _command(root: Path) -> list[str]:
    sets = (*TINY, f"data.root={root / 'data'}", f"runs_dir={root / 'runs'}", *MGN)
    return [sys.executable, "-m", "clods_bench.cli", "run", "cdg", "--sim", "mgn", *[a for s in sets for a in ("--set", s)]]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _result(runs: Path) -> dict:
    (path,) = runs.glob("cdg/*/*/seed_0/result.json")
    return json.loads(path.read_text())


def test_sigterm_prints_the_interrupted_line_and_the_rerun_resumes(tmp_path: Path) -> None:
    proc = subprocess.Popen(_command(tmp_path), cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not list((tmp_path / "runs").glob("fit_cache/mgn-*/mgn.ckpt")):  # training, its first checkpoint written
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no checkpoint within 240 s"
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines()[-1] == "interrupted by SIGTERM; finished work is kept and the next run resumes"
    assert "Traceback" not in err and not list((tmp_path / "runs").glob("cdg/*/*/seed_0/result.json"))

    assert main(_command(tmp_path)[3:]) == 0  # the same command again (here, in this process)
    resumed = _result(tmp_path / "runs")
    assert resumed["timings"]["fit/resumed_from_step"] >= 5.0
    clean = [*_command(tmp_path)[3:], "--set", f"runs_dir={tmp_path / 'clean-runs'}"]  # the same data, a fit never stopped
    assert main(clean) == 0
    assert resumed["extra"]["stage_digests"] == _result(tmp_path / "clean-runs")["extra"]["stage_digests"]
