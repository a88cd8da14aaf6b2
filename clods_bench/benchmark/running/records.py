"""Run records: one directory per (task, label, config) with per-seed results and an aggregate.

Layout: `<runs_dir>/<task>/<label>/<scene>-<preset>-<hash>/` holding `config.yaml`
(resolved config), `seed_<k>/result.json` (one per finished seed; the run resumes by
skipping these) and `record.json` (all seeds, mean +- std, timings, versions, commit).
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterator, Sequence

from clods_bench import numerics
from clods_bench.atomic import write_json
from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.descriptors import TaskResult
from clods_bench.benchmark.core.registry import Registry
from clods_bench.benchmark.running.environment import git_commit, package_versions
from clods_bench.benchmark.scoring.metrics import mean_std
from clods_bench.errors import ClodsError

RESULT_FILE = "result.json"
RECORD_FILE = "record.json"


def default_label(cfg: RunConfig, registry: Registry) -> str:
    """Row label: the explicit label, else the one the task declares for the config (`TaskSpec.row_label`, e.g. CDG's
    CloDS rows), else the plugin name(s), '*' marking the first-half training subset."""
    if cfg.label:
        return cfg.label
    declare = getattr(registry.get("task", cfg.task), "row_label", None)
    declared = declare(cfg) if declare is not None else None
    if declared:
        return str(declared)
    parts = [p for p in (cfg.sim, cfg.renderer, cfg.predictor) if p]
    label = "+".join(parts) or cfg.task
    return label + ("*" if cfg.train_subset == "first_half" else "")


def record_dir(cfg: RunConfig, registry: Registry) -> Path:
    """Deterministic record directory: the same config (seeds aside) resumes into the same place. Its folder is
    named after the row label (`default_label`), its last part after a digest of the config."""
    ident = cfg.to_dict()
    for key in ("seeds", "progress", "runs_dir"):
        ident.pop(key)
    ident.pop("device", None)  # where it computes is in the options of the plugins it reaches (device_switch)
    ident["data"].pop("root")
    if ident["data"].get("path") is None:  # added with imported datasets: left out when unused, records keep their digest
        ident["data"].pop("path", None)
    # Only the options of the plugins the run uses: a preset gaining another simulator's or renderer's options
    # (a new plugin, built in or third-party) must not move every record.
    ident["sim_config"] = {cfg.sim: ident["sim_config"].get(cfg.sim, {})} if cfg.sim else {}
    ident["renderer_config"] = {cfg.renderer: ident["renderer_config"].get(cfg.renderer, {})} if cfg.renderer else {}
    if cfg.predictor is None:  # fields added with the dvc task: left out when unused, so older records keep their digest
        ident.pop("predictor")
        ident.pop("video_config")
    else:
        ident["video_config"] = {cfg.predictor: ident["video_config"].get(cfg.predictor, {})}
    if numerics.numeric_mode() != "deterministic":  # the host's own floating-point paths: never mixed with
        ident["numeric_mode"] = numerics.numeric_mode()  # deterministic records (those keep their digest)
    digest = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:8]
    slug = re.sub(r"[^A-Za-z0-9_.+-]", "_", default_label(cfg, registry).replace("*", "-star"))
    return Path(cfg.runs_dir) / cfg.task / slug / f"{cfg.data.scene}-{cfg.preset}-{digest}"


def seed_result_path(rdir: Path, seed: int) -> Path:
    return rdir / f"seed_{seed}" / RESULT_FILE


def load_seed_result(rdir: Path, seed: int) -> dict[str, Any] | None:
    """A finished seed's result, or None when it has not finished (or its file is unreadable)."""
    path = seed_result_path(rdir, seed)
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        return None  # a torn file cannot happen with atomic writes; treat anything odd as unfinished


def reusable_seed_result(rdir: Path, seed: int, data_digests: Sequence[str] | None = None) -> dict[str, Any] | None:
    """A finished seed's result that a run may reuse, or None when it has not finished. A result made from other data
    (its recorded content digests differ from `data_digests`, those of the run's datasets now) or under other numeric
    pins is a ClodsError: reusing it would put numbers of another computation in the table. Results written before
    these fields were recorded cannot be told apart and are reused."""
    done = load_seed_result(rdir, seed)
    if done is None:
        return None
    path = seed_result_path(rdir, seed)
    hint = "to rerun it, move its record folder away or use another runs_dir; `clods-bench tables` still reads it"
    had = done.get("data_digests")
    if data_digests is not None and isinstance(had, list) and list(had) != list(data_digests):
        raise ClodsError(f"seed {seed}'s result was made from other data (dataset content {', '.join(map(str, had))}, now "
                         f"{', '.join(data_digests)}): the data generator or the dataset changed since", where=str(path), hint=hint)  # fmt: skip
    made, now = done.get("numerics"), numerics.describe()
    if isinstance(made, dict) and made.get("mode") == now.get("mode") == "deterministic":
        was, current = made.get("pins_version"), now.get("pins_version")
        if was is not None and was != current:
            raise ClodsError(f"seed {seed}'s result was computed under numeric pins version {was}; this release computes with "
                             f"version {current}, so a rerun gives other numbers", where=str(path), hint=hint)  # fmt: skip
    return done


def save_seed_result(rdir: Path, seed: int, result: TaskResult, data_digests: Sequence[str] | None = None) -> dict[str, Any]:
    """Write a finished seed's result with its provenance: numeric mode and the content digests of the data it used."""
    payload = {"seed": seed, **asdict(result), "numerics": numerics.describe(), "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
    if data_digests is not None:
        payload["data_digests"] = list(data_digests)
    write_json(seed_result_path(rdir, seed), payload)
    return json.loads(json.dumps(payload, default=str))


def aggregate(cfg: RunConfig, label: str, rdir: Path, per_seed: dict[int, dict[str, Any]], extra_timings: dict[str, float]) -> dict[str, Any]:
    """Write `record.json` of the row `label`: mean +- std over seeds of every metric and timing, plus provenance."""
    seeds = sorted(per_seed)
    record = {
        "task": cfg.task,
        "label": label,
        "sim": cfg.sim,
        "renderer": cfg.renderer,
        "scene": cfg.data.scene,
        "preset": cfg.preset,
        "seeds": seeds,
        **summary(per_seed),
        "run_timings": extra_timings,
        "per_seed": {str(s): {"metrics": per_seed[s]["metrics"], "timings": per_seed[s]["timings"], "extra": per_seed[s].get("extra", {})} for s in seeds},
        "config": cfg.to_dict(),
        "versions": package_versions(),
        "numerics": numerics.describe(),
        "commit": git_commit(),
        "written": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    write_json(rdir / RECORD_FILE, record)
    return record


def summary(per_seed: dict[Any, dict[str, Any]]) -> dict[str, Any]:
    """{'metrics': {key: {'mean', 'std'}}, 'timings': {...}} over the given seeds' results."""
    out: dict[str, Any] = {}
    for section in ("metrics", "timings"):
        keys = sorted({k for r in per_seed.values() for k in r[section]})
        out[section] = {}
        for key in keys:
            m, sd = mean_std([_num(r[section].get(key)) for r in per_seed.values()])
            out[section][key] = {"mean": m, "std": sd}
    return out


def restrict(record: dict[str, Any], seeds: Sequence[int]) -> dict[str, Any]:
    """`record` as if only `seeds` had run: per-seed results kept for those, means and stds recomputed from them."""
    keep = {str(s): record["per_seed"][str(s)] for s in seeds if str(s) in record.get("per_seed", {})}
    if not keep:
        raise ClodsError(f"the record has none of the seeds {list(seeds)} (it has {record.get('seeds')})", where=str(record.get("label")))
    out = dict(record)
    out.update(summary(keep), per_seed=keep, seeds=sorted(int(s) for s in keep))
    return out


def iter_records(runs_dir: Path | Sequence[Path], task: str | None = None) -> Iterator[tuple[Path, dict[str, Any]]]:
    """Every readable `record.json` under `runs_dir` (optionally of one task), sorted by path.

    Several folders may be given (runs made on several machines, or committed records beside a fresh
    `runs_dir`); the same run (record path relative to its folder) found in two of them is an error, since
    one table row would then come from two records."""
    roots = [Path(runs_dir)] if isinstance(runs_dir, (str, Path)) else [Path(r) for r in runs_dir]
    seen: dict[Path, Path] = {}
    for root in roots:
        if not root.is_dir():
            raise ClodsError("runs directory not found", where=str(root))
        for path in sorted(root.rglob(RECORD_FILE)):
            rel = path.relative_to(root)
            if rel in seen:
                raise ClodsError(
                    "the same run is recorded in two runs folders", where=f"{seen[rel]} and {path}",
                    hint="drop one of them from --runs (or delete the stale record)",
                )  # fmt: skip
            seen[rel] = path
            try:
                rec = json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                raise ClodsError(f"malformed record JSON at line {exc.lineno}: {exc.msg}", where=str(path)) from None
            if task is None or rec.get("task") == task:
                yield path.parent, rec


def runs_label(runs_dir: Path | Sequence[Path]) -> str:
    """`runs_dir` (one folder or several) as it is named in messages."""
    return str(runs_dir) if isinstance(runs_dir, (str, Path)) else ", ".join(str(r) for r in runs_dir)


def _num(value: Any) -> float:
    return float("nan") if value is None else float(value)
