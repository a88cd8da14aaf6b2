"""examples/gpu/check.sh's CPU-side pieces: the results folder's name, the agreement tests it names, and the summary it
writes from its steps' logs, on a GPU's kind of output and on the CPU stand-in's."""

from __future__ import annotations

import datetime as dt
import json
import re
import subprocess
from pathlib import Path

import pytest

from tests.examples.example_module import load_example

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "examples" / "gpu" / "check.sh"


cs = load_example("examples/gpu/check_summary.py")


def test_the_results_folder_is_named_by_gpu_and_date() -> None:
    day = dt.date(2026, 12, 7)
    assert cs.results_folder(Path("results/gpu"), "NVIDIA H100 80GB HBM3", day) == Path("results/gpu/nvidia-h100-80gb-hbm3-2026-12-07")
    assert cs.results_folder(Path("r"), "NVIDIA H200", day) == Path("r/nvidia-h200-2026-12-07")
    assert cs.slug("  ") == "unknown" and cs.gpu_name("cpu") == "cpu"


def test_cuda_without_a_gpu_stops_the_check_in_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    import torch

    monkeypatch.setattr(cs.shutil, "which", lambda name: None)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit, match=r"^check.sh: DEVICE=cuda, but torch .* sees no CUDA GPU \(DEVICE=cpu runs the CPU stand-in\)$"):
        cs.gpu_name("cuda")


def test_the_agreement_tests_exist_and_skip_without_a_gpu() -> None:
    """Each id names a test function of its file whose body skips without CUDA (so on a GPU machine it runs)."""
    for test in cs.AGREEMENT_TESTS:
        path, name = test.split("[")[0].split("::")
        text = (ROOT / path).read_text()
        assert re.search(rf"^def {name}\(", text, re.M), test
        body = text.split(f"def {name}(", 1)[1].split("\ndef ", 1)[0]
        head = text.split(f"def {name}(", 1)[0].rsplit("\n\n\n", 1)[-1]  # its decorators
        assert re.search(r"skip", body + head) and re.search(r"cuda|gsplat", body + head, re.I), test


def test_the_script_parses_and_names_its_steps() -> None:
    assert subprocess.run(["bash", "-n", str(SCRIPT)], capture_output=True).returncode == 0
    text = SCRIPT.read_text()
    steps = re.findall(r"^step (\w+) ", text, re.M) + re.findall(r"^  (?:step|skip) (\w+) ", text, re.M)
    assert steps == ["env", "agreement", "switch", "fit", "infer", "sim", "gsplat", "gsplat"]


def _junit(path: Path, cases: dict[str, str]) -> None:
    rows = []
    for case, result in cases.items():
        module, name = case.split("::")
        classname = module[:-3].replace("/", ".")
        inner = {"passed": "", "skipped": '<skipped message="needs a CUDA GPU" />', "failed": '<failure message="images differ by 3e-3" />'}[result]
        rows.append(f'<testcase classname="{classname}" name="{name}" time="1.0">{inner}</testcase>')
    path.write_text(f'<?xml version="1.0"?><testsuites><testsuite name="pytest">{"".join(rows)}</testsuite></testsuites>')


def _results(tmp_path: Path, device: str, result: str, steps: str, gsplat: bool = True) -> Path:
    """A results folder as check.sh leaves it: env.json, steps.tsv, agreement.xml, a record, the timing files."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "env.json").write_text(json.dumps({"device": device, "gpu": "NVIDIA H100 80GB HBM3" if device != "cpu" else "cpu",
                                                   "torch": "2.11.0+cu130", "cuda": "13.0", "gsplat": "1.5.3", "cpu_threads": 16,
                                                   "clods_bench": "0.2.0", "commit": "abc"}))  # fmt: skip
    (tmp_path / "steps.tsv").write_text(steps)
    cases = {test: result for test in cs.AGREEMENT_TESTS}
    cases[cs.AGREEMENT_TESTS[0] + "[random]"] = cases.pop(cs.AGREEMENT_TESTS[0])  # a parametrised test: each case counts
    cases[cs.AGREEMENT_TESTS[0] + "[flat cloth]"] = "passed"
    cases["tests/benchmark/clods/test_stage0.py::test_a_bent_flag_is_reconstructed_from_its_rendered_views[cpu]"] = "failed"  # not listed
    _junit(tmp_path / "agreement.xml", cases)
    record = tmp_path / "runs" / "nvs" / "smgs" / "flag-ci-12345678"
    record.mkdir(parents=True)
    opts = {"backend": "gsplat", "device": "cuda", "iterations": 300} if gsplat else {"backend": "cpu", "device": "cpu"}
    (record / "config.yaml").write_text(json.dumps({"task": "nvs", "renderer": "smgs", "sim": None, "predictor": None, "device": device,
                                                    "renderer_config": {"smgs": opts}}))  # fmt: skip
    (tmp_path / "paper_size_fit.json").write_text(json.dumps({"views": 25, "size": 800, "iterations": 3, "cpu_threads": 16, "gpu": "x", "rows": [
        {"renderer": "smgs", "setup": "gpu", "device": "cuda", "backend": "gsplat", "fit_ms": 131.0, "stage2_ms": 31.0, "loss_final": 0.0123}]}))
    (tmp_path / "infer").mkdir()
    (tmp_path / "infer" / "infer_paper_cuda.json").write_text(json.dumps({"preset": "paper", "device": "cuda", "frames": 3,
        "clods": {"total_ms": 30.2}, "traditional": {"total_ms": 376.6}, "ratio_traditional_over_clods": 12.47}))  # fmt: skip
    (tmp_path / "sim.log").write_text("ground truth ...\n   clods-bench bench sim (1579-node flag, 10 rollout steps, cpu)\n| mgn | 1.17 |\n")
    return tmp_path


STEPS_OK = "env\t60\t4\t0\ngsplat\t150\t2\t0\nagreement\t200\t95\t0\nswitch\t90\t41\t0\nfit\t90\t70\t0\ninfer\t75\t28\t0\nsim\t75\t40\t0\n"


def test_a_green_gpu_check_is_confirmed(tmp_path: Path) -> None:
    s = cs.summarize(_results(tmp_path, "cuda", "passed", STEPS_OK))
    assert s["confirmed"] and s["verdict"].startswith("GPU path confirmed on NVIDIA H100 80GB HBM3")
    assert s["total_seconds"] == 280 and [r["result"] for r in s["agreement"]] == ["passed"] * 7
    assert s["agreement"][0]["test"].endswith("[flat cloth]") and s["agreement"][4]["test"].endswith("[gsplat]")
    assert s["switch"] == [{"record": "runs/nvs/smgs/flag-ci-12345678", "device": "cuda", "plugin": "renderer_config.smgs",
                            "options": {"backend": "gsplat", "device": "cuda"}}]  # fmt: skip
    page = (tmp_path / "summary.md").read_text()
    assert "| agreement | ok | 95.0 | 200 |" in page and "| smgs | gpu (gsplat, cuda) | 131.0 | 31.0 | 0.0123 |" in page
    assert "CloDS 30.2 ms per frame, the traditional pipeline 376.6 ms (12.47x)" in page and "| mgn | 1.17 |" in page
    assert json.loads((tmp_path / "summary.json").read_text())["confirmed"] is True
    assert cs.main(["summarize", str(tmp_path)]) == 0


def test_a_skipped_or_failed_test_a_timed_out_step_or_a_run_left_on_the_cpu_is_not_a_confirmation(tmp_path: Path) -> None:
    for i, (result, steps, gsplat) in enumerate([
        ("skipped", STEPS_OK, True),
        ("failed", STEPS_OK, True),
        ("passed", STEPS_OK.replace("sim\t75\t40\t0", "sim\t75\t75\t124"), True),
        ("passed", STEPS_OK, False),
    ]):  # fmt: skip
        s = cs.summarize(_results(tmp_path / str(i), "cuda", result, steps, gsplat))
        assert not s["confirmed"] and s["verdict"] == "GPU path NOT confirmed on NVIDIA H100 80GB HBM3: see the steps and tests below", i
        assert cs.main(["summarize", str(tmp_path / str(i))]) == 1
    steps = cs.read_steps(tmp_path / "2")
    assert steps[-1] == {"step": "sim", "status": "timed out after its 75 s", "seconds": 75.0, "budget": 75, "rc": "124"}
    assert cs.agreement(cs.read_junit(tmp_path / "1" / "agreement.xml"), True)[0][1]["detail"] == "images differ by 3e-3"


def test_the_cpu_stand_in_says_it_confirms_nothing(tmp_path: Path) -> None:
    steps = STEPS_OK.replace("gsplat\t150\t2\t0", "gsplat\t0\t0\tskip:DEVICE=cpu")
    s = cs.summarize(_results(tmp_path / "a", "cpu", "skipped", steps, gsplat=False))
    assert not s["confirmed"] and s["finished"]
    assert s["verdict"] == "CPU stand-in (DEVICE=cpu): the steps ran on the CPU at a tiny size; nothing about a GPU is confirmed"
    assert cs.main(["summarize", str(tmp_path / "a")]) == 0  # the script's own check passed
    s = cs.summarize(_results(tmp_path / "b", "cpu", "skipped", steps.replace("fit\t90\t70\t0", "fit\t90\t3\t1"), gsplat=False))
    assert "not all of them to the end" in s["verdict"] and cs.main(["summarize", str(tmp_path / "b")]) == 1
    assert "| fit | failed (exit 1) | 3.0 | 90 |" in (tmp_path / "b" / "summary.md").read_text()
