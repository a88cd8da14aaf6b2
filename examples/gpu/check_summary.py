"""The pieces of `examples/gpu/check.sh` that are Python: the results folder's name, what the machine is, and the
summary of a check's steps, tests and timings (summary.md, summary.json).

    python examples/gpu/check_summary.py folder --device cuda [--root results/gpu]   # prints results/gpu/<gpu>-<date>
    python examples/gpu/check_summary.py env --device cuda --out env.json             # torch, CUDA, GPU, gsplat, commit
    python examples/gpu/check_summary.py tests                                        # the agreement tests' ids
    python examples/gpu/check_summary.py summarize RESULTS                            # RESULTS/summary.{md,json}

Standard library only at import (torch is imported where the machine is read), so the summary is written even when
a step broke the environment.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

AGREEMENT_TESTS = (
    "tests/splatting/test_backends.py::test_gsplat_backend_matches_the_reference_and_the_cpu",
    "tests/splatting/test_surfel_gsplat.py::test_gsplat_kernels_match_the_cpu_backend",
    "tests/plugins/renderers/test_device.py::test_a_fit_on_the_gpu_matches_the_cpu_fit",
    "tests/benchmark/clods/test_stage0.py::test_a_bent_flag_is_reconstructed_from_its_rendered_views[gsplat]",
    "tests/plugins/simulators/test_mgn.py::test_training_and_rollout_on_a_gpu_match_the_cpu",
    "tests/plugins/video/test_trainer.py::test_training_and_prediction_on_a_gpu_match_the_cpu",
)
"""The CPU-against-GPU tests, one per backend (splatting, 2DGS surfels, the renderers' fits, stage 0 on gsplat, the
learned simulators, the video predictors); each skips without a GPU and states its tolerances. Stage 0's is its
gsplat case alone: the CPU case (2 minutes on one thread) bounds the same error against the truth, and CI runs it."""

TIMED_OUT = (124, 137)
"""Exit codes of `timeout`: the step ran past its budget (124: stopped by the signal; 137: killed after the grace)."""


def slug(name: str) -> str:
    """A folder-safe lower-case name: 'NVIDIA H100 80GB HBM3' -> 'nvidia-h100-80gb-hbm3'."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "unknown"


def results_folder(root: Path, gpu_name: str, day: dt.date) -> Path:
    """`root/<gpu>-<YYYY-MM-DD>`: where one check's logs and summary go."""
    return Path(root) / f"{slug(gpu_name)}-{day.isoformat()}"


def gpu_name(device: str) -> str:
    """The first GPU's name (nvidia-smi, else torch), or 'cpu' for the CPU stand-in; SystemExit(2) with one line when
    a CUDA device is asked for and none is there."""
    if device == "cpu":
        return "cpu"
    if shutil.which("nvidia-smi"):
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True)
        names = [line.strip() for line in out.stdout.splitlines() if line.strip()]
        if out.returncode == 0 and names:
            return names[0]
    import torch

    if not torch.cuda.is_available():
        raise SystemExit(f"check.sh: DEVICE={device}, but torch {torch.__version__} sees no CUDA GPU (DEVICE=cpu runs the CPU stand-in)")
    return torch.cuda.get_device_name(0)


def environment(device: str) -> dict[str, Any]:
    """What the check ran on: GPU, driver, torch and CUDA, gsplat, clods-bench and its commit, CPU threads."""
    import torch

    env: dict[str, Any] = {"device": device, "gpu": gpu_name(device), "torch": torch.__version__, "cuda": torch.version.cuda,
                           "cpu_threads": torch.get_num_threads(), "python": sys.version.split()[0]}  # fmt: skip
    if device != "cpu" and shutil.which("nvidia-smi"):
        out = subprocess.run(["nvidia-smi", "--query-gpu=driver_version,memory.total", "--format=csv,noheader"], capture_output=True, text=True)
        env["driver, memory"] = out.stdout.strip().splitlines()[0] if out.returncode == 0 and out.stdout.strip() else None
    try:
        import gsplat

        env["gsplat"] = gsplat.__version__
    except ImportError:
        env["gsplat"] = None
    import clods_bench
    from clods_bench.benchmark.running.environment import git_commit

    env["clods_bench"] = getattr(clods_bench, "__version__", None)
    env["commit"] = git_commit()
    return env


def read_steps(results: Path) -> list[dict[str, Any]]:
    """The steps check.sh recorded in `steps.tsv` (name, budget s, seconds, exit code or 'skip:<why>'), with a status."""
    steps = []
    path = results / "steps.tsv"
    for line in path.read_text().splitlines() if path.is_file() else []:
        name, budget, seconds, rc = (line.split("\t") + ["", "", "", ""])[:4]
        if rc.startswith("skip"):
            status = "not run: " + rc.partition(":")[2]
        elif rc.lstrip("-").isdigit() and int(rc) == 0:
            status = "ok"
        elif rc.lstrip("-").isdigit() and int(rc) in TIMED_OUT:
            status = f"timed out after its {budget} s"
        else:
            status = f"failed (exit {rc})"
        steps.append({"step": name, "status": status, "seconds": float(seconds or 0), "budget": int(budget or 0), "rc": rc})
    return steps


def read_junit(path: Path) -> dict[str, dict[str, str]]:
    """pytest's JUnit XML as {test id: {'result': passed|failed|error|skipped, 'detail': message}}."""
    if not path.is_file():
        return {}
    out = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        module = case.get("classname", "").replace(".", "/")
        test_id = f"{module}.py::{case.get('name')}"
        result, detail = "passed", ""
        for tag in ("failure", "error", "skipped"):
            node = case.find(tag)
            if node is not None:
                result = {"failure": "failed", "error": "error", "skipped": "skipped"}[tag]
                detail = (node.get("message") or "").splitlines()[0][:300] if node.get("message") else ""
                break
        out[test_id] = {"result": result, "detail": detail}
    return out


def agreement(results: dict[str, dict[str, str]], on_gpu: bool) -> tuple[list[dict[str, str]], bool]:
    """One row per agreement test case (every parametrisation) and whether the GPU path is confirmed: on a GPU every
    case of every test in AGREEMENT_TESTS ran and passed (a skip there is not a confirmation)."""
    rows, confirmed = [], on_gpu
    for test in AGREEMENT_TESTS:
        cases = {k: v for k, v in results.items() if k == test or k.startswith(test + "[")}
        if not cases:
            rows.append({"test": test, "result": "not run", "detail": ""})
            confirmed = False
        for case, r in sorted(cases.items()):
            rows.append({"test": case, **r})
            confirmed = confirmed and r["result"] == "passed"
    return rows, confirmed


def timings(results: Path) -> dict[str, Any]:
    """The timing steps' numbers: paper_size_fit.py's rows, bench infer's medians per frame, bench sim's table text."""
    out: dict[str, Any] = {}
    fit = results / "paper_size_fit.json"
    if fit.is_file():
        out["fit"] = json.loads(fit.read_text())
    for path in sorted((results / "infer").glob("infer_*.json")):
        r = json.loads(path.read_text())
        out.setdefault("infer", []).append({"preset": r.get("preset"), "device": r.get("device"), "frames": r.get("frames"),
                                            "clods_ms": r["clods"]["total_ms"], "traditional_ms": r["traditional"]["total_ms"],
                                            "ratio": r.get("ratio_traditional_over_clods")})  # fmt: skip
    sim = results / "sim.log"
    if sim.is_file():
        lines = sim.read_text().splitlines()
        start = next((i for i, line in enumerate(lines) if "bench sim" in line and "flag" in line), None)
        out["sim_table"] = "\n".join(lines[start:] if start is not None else lines[-20:])
    return out


def switch_run(results: Path) -> list[dict[str, Any]]:
    """What `run ... --device` wrote into the options of the plugins it reached (each record's config.yaml)."""
    import yaml

    rows = []
    for path in sorted((results / "runs").glob("*/*/*/config.yaml")):
        cfg = yaml.safe_load(path.read_text())
        for section, name in (("sim_config", cfg.get("sim")), ("renderer_config", cfg.get("renderer")), ("video_config", cfg.get("predictor"))):
            opts = (cfg.get(section) or {}).get(name) or {}
            if name:
                rows.append({"record": str(path.parent.relative_to(results)), "device": cfg.get("device"), "plugin": f"{section}.{name}",
                             "options": {k: opts[k] for k in ("backend", "device") if k in opts}})  # fmt: skip
    return rows


def summarize(results: Path) -> dict[str, Any]:
    """Write RESULTS/summary.json and summary.md from what the steps left there; return the summary."""
    env = json.loads((results / "env.json").read_text()) if (results / "env.json").is_file() else {}
    on_gpu = env.get("device", "cpu") != "cpu"
    steps = read_steps(results)
    rows, confirmed = agreement(read_junit(results / "agreement.xml"), on_gpu)
    switch = switch_run(results)
    switched = any(r["options"].get("device", "cpu") != "cpu" or r["options"].get("backend") == "gsplat" for r in switch)
    finished = bool(steps) and all(s["status"] == "ok" or s["status"] == "not run: DEVICE=cpu" for s in steps)
    confirmed = confirmed and switched and finished
    if not on_gpu:
        verdict = ("CPU stand-in (DEVICE=cpu): the steps ran on the CPU at a tiny size" + ("" if finished else ", not all of them to the end")
                   + "; nothing about a GPU is confirmed")  # fmt: skip
    elif confirmed:
        verdict = f"GPU path confirmed on {env.get('gpu')}: every agreement test passed, --device reached the run, every step finished"
    else:
        verdict = f"GPU path NOT confirmed on {env.get('gpu')}: see the steps and tests below"
    summary = {"verdict": verdict, "confirmed": confirmed, "finished": finished, "environment": env, "steps": steps, "agreement": rows, "switch": switch,
               "timings": timings(results), "total_seconds": sum(s["seconds"] for s in steps)}  # fmt: skip
    (results / "summary.json").write_text(json.dumps(summary, indent=1))
    (results / "summary.md").write_text(markdown(summary))
    return summary


def markdown(s: dict[str, Any]) -> str:
    """The summary as a page: verdict, machine, steps, tests, the device switch, timings."""
    env = s["environment"]
    lines = [f"# GPU check: {env.get('gpu', '?')}, {dt.date.today().isoformat()}", "", f"**{s['verdict']}.**", "",
             f"clods-bench {env.get('clods_bench')} at commit {env.get('commit') or 'unknown'}; torch {env.get('torch')} (CUDA "
             f"{env.get('cuda')}), gsplat {env.get('gsplat')}; {env.get('cpu_threads')} CPU threads"
             + (f"; driver, memory: {env['driver, memory']}" if env.get("driver, memory") else "")
             + f". Steps took {s['total_seconds']:.0f} s.", "",
             "| step | status | seconds | budget (s) |", "| --- | --- | --- | --- |"]  # fmt: skip
    lines += [f"| {x['step']} | {x['status']} | {x['seconds']:.1f} | {x['budget']} |" for x in s["steps"]]
    lines += ["", "## CPU against GPU (the tests' own tolerances)", "", "| test | result | detail |", "| --- | --- | --- |"]
    lines += [f"| `{r['test']}` | {r['result']} | {r['detail'].replace('|', '/')} |" for r in s["agreement"]]
    lines += ["", "## The device switch (`run nvs --renderer smgs --device ...`)", ""]
    lines += [f"- `{r['record']}`: device {r['device']}; `{r['plugin']}`: {r['options']}" for r in s["switch"]] or ["- no record written"]
    t = s["timings"]
    lines += ["", "## Timings", ""]
    if "fit" in t:
        f = t["fit"]
        lines += [f"`paper_size_fit.py`: {f['views']} views of {f['size']} px, {plural(f['iterations'], 'iteration')}, {f['cpu_threads']} CPU threads", "",
                  "| renderer | setup | fit ms / iteration | stage-2 ms / step | final loss |", "| --- | --- | --- | --- | --- |"]  # fmt: skip
        lines += [f"| {r['renderer']} | {r['setup']} ({r['backend']}, {r['device']}) | {r['fit_ms']:.1f} | {r['stage2_ms']:.1f} | {r['loss_final']:.4f} |"
                  for r in f["rows"]]  # fmt: skip
        lines.append("")
    for r in t.get("infer", []):
        lines.append(f"`bench infer --preset {r['preset']} --device {r['device']}` ({plural(r['frames'], 'frame')}): CloDS {r['clods_ms']:.1f} ms per "
                     f"frame, the traditional pipeline {r['traditional_ms']:.1f} ms ({r['ratio']:.2f}x)")  # fmt: skip
    if "sim_table" in t:
        lines += ["", "`bench sim`:", "", "```text", t["sim_table"], "```"]
    return "\n".join(lines) + "\n"


def plural(n: Any, word: str) -> str:
    """'1 frame', '3 frames'."""
    return f"{n} {word}" + ("" if n == 1 else "s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    p = sub.add_parser("folder", help="print the results folder: ROOT/<gpu>-<date>")
    p.add_argument("--device", default="cuda")
    p.add_argument("--root", type=Path, default=Path("results/gpu"))
    p = sub.add_parser("env", help="write what the machine is, as JSON")
    p.add_argument("--device", default="cuda")
    p.add_argument("--out", type=Path, required=True)
    sub.add_parser("tests", help="print the agreement tests' ids, one a line")
    p = sub.add_parser("summarize", help="write RESULTS/summary.md and summary.json")
    p.add_argument("results", type=Path)
    args = ap.parse_args(argv)
    if args.what == "folder":
        print(results_folder(args.root, gpu_name(args.device), dt.date.today()))
    elif args.what == "env":
        env = environment(args.device)
        args.out.write_text(json.dumps(env, indent=1))
        print(json.dumps(env, indent=1))
    elif args.what == "tests":
        print("\n".join(AGREEMENT_TESTS))
    else:
        s = summarize(args.results)
        print(s["verdict"])
        return 0 if s["confirmed"] or (s["environment"].get("device", "cpu") == "cpu" and s["finished"]) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
