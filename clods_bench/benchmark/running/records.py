"""Run records: one directory per (task, label, config) with per-seed results and an aggregate.

Layout: `<runs_dir>/<task>/<label>/<scene>-<preset>-<hash>/` holding `config.yaml` (the resolved config of the
last command), `seed_<k>/result.json` (one per finished seed; a run resumes by skipping these) and `record.json`
(every seed finished for the configuration, by any command: mean +- std, timings, versions, commit). The record is
rebuilt from every reusable `seed_<k>/result.json` of its folder under an exclusive lock (`record.lock`), so running
more seeds adds to it, running fewer removes none, and concurrent runs of different seeds all land.

Both JSON files carry an `identity` block (version `IDENTITY_VERSION`: the full config digest whose first 8 hex
digits name the folder, the data content digests, the numeric mode and pins) and a content hash
(`clods_bench.integrity`), both checked when read. Files written before these fields existed are read as before.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterator, Sequence

from clods_bench import numerics
from clods_bench import integrity
from clods_bench.atomic import file_lock, write_json
from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.descriptors import TaskResult
from clods_bench.benchmark.core.registry import Registry
from clods_bench.benchmark.running.environment import git_commit, package_versions
from clods_bench.benchmark.scoring.metrics import mean_std
from clods_bench.errors import ClodsError

RESULT_FILE = "result.json"
RECORD_FILE = "record.json"
RECORD_LOCK = "record.lock"
IDENTITY_VERSION = 1
"""Version of the `identity` block in `result.json` and `record.json`; a file of a later version is refused."""
CONSISTENCY_RTOL = 1e-9
"""How far a record's stored mean or std may be from the one recomputed from its per-seed values (summation order
only: a stored value is the same sum, perhaps in another seed order)."""


def default_label(cfg: RunConfig, registry: Registry) -> str:
    """Row label: the explicit label, else the one the task declares for the config (`TaskSpec.row_label`, e.g. CDG's
    CloDS rows), else the plugin's own row label (`PluginSpec.row_label`: its published name, '*' marking the
    first-half training subset, then how a variant differs), else the plugin names joined by '+'."""
    if cfg.label:
        return cfg.label
    declare = getattr(registry.get("task", cfg.task), "row_label", None)
    declared = declare(cfg) if declare is not None else None
    if declared:
        return str(declared)
    first_half = cfg.train_subset == "first_half"
    used = [(kind, name) for kind, name in (("simulator", cfg.sim), ("renderer", cfg.renderer), ("video_predictor", cfg.predictor)) if name]
    if len(used) == 1:
        spec = registry.get(*used[0])
        if hasattr(spec, "row_label"):
            return str(spec.row_label(first_half))
    label = "+".join(name for _, name in used) or cfg.task
    return label + ("*" if first_half else "")


def config_digest(cfg: RunConfig) -> str:
    """SHA-256 (hex) of what decides a run's numbers in its config: everything but seeds, progress, where records and
    data lie, and the options of plugins it does not use. Its first 8 digits name the record folder."""
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
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()


def record_dir(cfg: RunConfig, registry: Registry) -> Path:
    """Deterministic record directory: the same config (seeds aside) resumes into the same place. Its folder is
    named after the row label (`default_label`), its last part after the config digest (`config_digest`)."""
    slug = re.sub(r"[^A-Za-z0-9_.+-]", "_", default_label(cfg, registry).replace("*", "-star"))
    return Path(cfg.runs_dir) / cfg.task / slug / f"{cfg.data.scene}-{cfg.preset}-{config_digest(cfg)[:8]}"


def record_identity(cfg: RunConfig, data_digests: Sequence[str] | None) -> dict[str, Any]:
    """What decides a record's numbers, versioned: config digest, data content digests, numeric mode and pins."""
    now = numerics.describe()
    return {"version": IDENTITY_VERSION, "config": config_digest(cfg), "data": None if data_digests is None else list(data_digests),
            "numerics": {"mode": now.get("mode"), "pins_version": now.get("pins_version")}}  # fmt: skip


def require_seeds(cfg: RunConfig) -> None:
    """Refuse a run without seeds before any work (it would replace a record with one of no seeds)."""
    if not list(cfg.seeds):
        raise ClodsError("is empty: a run needs at least one seed", where="seeds", hint="e.g. --set seeds=[0]")


def seed_result_path(rdir: Path, seed: int) -> Path:
    return rdir / f"seed_{seed}" / RESULT_FILE


def load_seed_result(rdir: Path, seed: int) -> dict[str, Any] | None:
    """A finished seed's result, or None when it has not finished (or its file is torn); a result whose content
    differs from its content hash is a ClodsError naming it."""
    path = seed_result_path(rdir, seed)
    if not path.is_file():
        return None
    try:
        done = json.loads(path.read_text())
    except json.JSONDecodeError:
        return None  # a torn file cannot happen with atomic writes; treat anything odd as unfinished
    if not isinstance(done, dict):
        return None
    return integrity.check_json(done, path, f"delete {path.parent} to run seed {seed} again")


def reusable_seed_result(rdir: Path, seed: int, data_digests: Sequence[str] | None = None, config: str | None = None) -> dict[str, Any] | None:
    """A finished seed's result that a run may reuse, or None when it has not finished. A result made from other data
    (its recorded content digests differ from `data_digests`, those of the run's datasets now), under other numeric
    pins, for another config digest (`config`) or by a later identity version is a ClodsError: reusing it would put
    numbers of another computation in the table. Results written before these fields were recorded cannot be told
    apart and are reused."""
    done = load_seed_result(rdir, seed)
    if done is None:
        return None
    problem = _reuse_problem(done, seed, seed_result_path(rdir, seed), data_digests, config)
    if problem is not None:
        raise problem
    return done


def _reuse_problem(done: dict[str, Any], seed: int, path: Path, data_digests: Sequence[str] | None, config: str | None) -> ClodsError | None:
    """Why a finished seed's result may not be reused by a run of `config` on data `data_digests` (None: it may)."""
    hint = "to rerun it, move its record folder away or use another runs_dir; `clods-bench tables` still reads it"
    ident = done.get("identity")
    if isinstance(ident, dict):
        if _newer(ident):
            return ClodsError(f"seed {seed}'s result has record identity version {ident.get('version')!r}; this release reads "
                              f"up to version {IDENTITY_VERSION}", where=str(path), hint="use the clods-bench that wrote it")  # fmt: skip
        if config is not None and ident.get("config") not in (None, config):
            return ClodsError(f"seed {seed}'s result belongs to another configuration (config digest {str(ident.get('config'))[:8]}, "
                              f"this folder's is {config[:8]})", where=str(path), hint="it was copied here; move it back or delete it")  # fmt: skip
    had = done.get("data_digests")
    if data_digests is not None and isinstance(had, list) and list(had) != list(data_digests):
        return ClodsError(f"seed {seed}'s result was made from other data (dataset content {', '.join(map(str, had))}, now "
                          f"{', '.join(data_digests)}): the data generator or the dataset changed since", where=str(path), hint=hint)  # fmt: skip
    made, now = done.get("numerics"), numerics.describe()
    if isinstance(made, dict) and made.get("mode") == now.get("mode") == "deterministic":
        was, current = made.get("pins_version"), now.get("pins_version")
        if was is not None and was != current:
            return ClodsError(f"seed {seed}'s result was computed under numeric pins version {was}; this release computes with "
                              f"version {current}, so a rerun gives other numbers", where=str(path), hint=hint)  # fmt: skip
    return None


def _newer(ident: dict[str, Any]) -> bool:
    version = ident.get("version")
    return not isinstance(version, int) or version > IDENTITY_VERSION


def save_seed_result(rdir: Path, seed: int, result: TaskResult, data_digests: Sequence[str] | None = None,
                     identity: dict[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """Write a finished seed's result with its provenance (numeric mode, the content digests of the data it used, the
    record identity) and its content hash."""
    payload = {"seed": seed, **asdict(result), "numerics": numerics.describe(), "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
    if data_digests is not None:
        payload["data_digests"] = list(data_digests)
    if identity is not None:
        payload["identity"] = dict(identity)
    write_json(seed_result_path(rdir, seed), integrity.seal_json(payload))
    return json.loads(json.dumps(payload, default=str))


def finished_seeds(rdir: Path) -> list[int]:
    """The seeds with a `seed_<k>/result.json` in the record folder, in order."""
    found = []
    for path in rdir.glob(f"seed_*/{RESULT_FILE}"):
        tail = path.parent.name[len("seed_"):]
        if tail.lstrip("-").isdigit():
            found.append(int(tail))
    return sorted(found)


def seed_results(rdir: Path, data_digests: Sequence[str] | None, config: str | None) -> tuple[dict[int, dict[str, Any]], dict[int, str]]:
    """({seed: result} of every reusable finished seed in the folder, by seed; {seed: why} of those left out because they
    were made from other data, under other pins or for another config). A result that fails its content hash is a
    ClodsError: it is never used, nor silently left out."""
    kept: dict[int, dict[str, Any]] = {}
    left: dict[int, str] = {}
    for seed in finished_seeds(rdir):
        done = load_seed_result(rdir, seed)
        if done is None:
            continue
        problem = _reuse_problem(done, seed, seed_result_path(rdir, seed), data_digests, config)
        if problem is None:
            kept[seed] = done
        else:
            left[seed] = problem.what
    return kept, left


def aggregate(cfg: RunConfig, label: str, rdir: Path, extra_timings: dict[str, float], data_digests: Sequence[str] | None = None) -> dict[str, Any]:
    """Write `record.json` of the row `label` from every reusable seed result in `rdir` (`seed_results`), under the
    record lock: mean +- std over those seeds of every metric and timing, the identity, provenance, a content hash."""
    identity = record_identity(cfg, data_digests)
    with file_lock(rdir / RECORD_LOCK):
        per_seed, left = seed_results(rdir, data_digests, identity["config"])
        if not per_seed:
            raise ClodsError("no finished seed to record", where=str(rdir), hint="run at least one seed of this configuration")
        seeds = sorted(per_seed)
        record = {
            "task": cfg.task,
            "label": label,
            "sim": cfg.sim,
            "renderer": cfg.renderer,
            "scene": cfg.data.scene,
            "preset": cfg.preset,
            "seeds": seeds,
            **summary({s: per_seed[s] for s in seeds}),
            "run_timings": extra_timings,
            "per_seed": {str(s): {"metrics": per_seed[s]["metrics"], "timings": per_seed[s]["timings"], "extra": per_seed[s].get("extra", {})} for s in seeds},
            "config": cfg.to_dict(),
            "identity": identity,
            "versions": package_versions(),
            "numerics": numerics.describe(),
            "commit": git_commit(),
            "written": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        if left:  # finished seeds of other data or pins: named, not averaged in
            record["left_out"] = {str(s): why for s, why in sorted(left.items())}
        write_json(rdir / RECORD_FILE, integrity.seal_json(record))
    return record


def summary(per_seed: dict[Any, dict[str, Any]], sections: Sequence[str] = ("metrics", "timings")) -> dict[str, Any]:
    """{'metrics': {key: {'mean', 'std'}}, 'timings': {...}} over the given seeds' results."""
    out: dict[str, Any] = {}
    for section in sections:
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


def read_record(path: Path) -> dict[str, Any]:
    """The `record.json` at `path`, checked: its content hash, and its identity (a version this release reads, and the
    config digest its folder is named after). One ClodsError naming the file and what to do otherwise."""
    path = Path(path)
    remedy = record_remedy(path.parent)
    rec = integrity.read_json(path, remedy)
    ident = rec.get("identity")
    if isinstance(ident, dict):
        if _newer(ident):
            raise ClodsError(f"record identity version {ident.get('version')!r}; this release reads up to version {IDENTITY_VERSION}",
                             where=str(path), hint="use the clods-bench that wrote it")  # fmt: skip
        folder = path.parent.name.rsplit("-", 1)[-1]
        config = str(ident.get("config") or "")
        if re.fullmatch(r"[0-9a-f]{8}", folder) and config and not config.startswith(folder):
            raise ClodsError(f"the record belongs to configuration {config[:8]}, its folder is named for {folder}", where=str(path),
                             hint="it was copied into another record's folder; move it back or delete it")  # fmt: skip
    return rec


def record_remedy(rdir: Path) -> str:
    """What to do about a damaged `record.json` in `rdir`: rebuild it from the seed results beside it."""
    task = rdir.parent.parent.name or "TASK"
    return f"rebuild it from its seed results: clods-bench run {task} --config {rdir / 'config.yaml'}"


def check_consistent(rec: dict[str, Any], where: str) -> None:
    """Refuse a record whose means or stds differ from those recomputed from its per-seed values (one ClodsError naming
    `where` and the first metric that disagrees). A record without per-seed values (hand-written) is not checked."""
    per_seed = rec.get("per_seed")
    if not isinstance(per_seed, dict):
        return
    hint = f"the record was edited or damaged; {record_remedy(Path(where).parent)}"
    listed = sorted((str(s) for s in rec.get("seeds") or []), key=_by_value)
    if sorted(per_seed, key=_by_value) != listed:
        raise ClodsError(f"lists seeds {_seed_list(listed)} but holds per-seed values of {_seed_list(per_seed)}", where=where, hint=hint)
    if not per_seed:
        return
    entries = [per_seed[s] for s in listed]
    sections = [sec for sec in ("metrics", "timings") if all(isinstance(e, dict) and isinstance(e.get(sec), dict) for e in entries)]
    again = summary({s: {sec: e[sec] for sec in sections} for s, e in zip(listed, entries)}, sections)
    for section in sections:  # a section the per-seed values lack (a hand-written record) is not checked
        stored = rec.get(section) or {}
        for key in sorted(set(again[section]) | set(stored)):
            want = again[section].get(key, {})
            got = stored.get(key) if isinstance(stored.get(key), dict) else {}
            for stat in ("mean", "std"):
                if not _same(got.get(stat), want.get(stat)):
                    raise ClodsError(f"{section[:-1]} '{key}': {stat} {got.get(stat)} but its per-seed values give {want.get(stat)}",
                                     where=where, hint=hint)  # fmt: skip


def _by_value(seed: str) -> tuple[int, str]:
    """Sort key of a seed written as text: by its number."""
    return (int(seed) if seed.lstrip("-").isdigit() else 0, seed)


def _seed_list(seeds: Any) -> str:
    """Seeds as a sorted list for a message."""
    return "[" + ", ".join(sorted((str(s) for s in seeds), key=_by_value)) + "]"


def _same(stored: Any, recomputed: Any) -> bool:
    try:
        a, b = _num(stored), _num(recomputed)
    except (TypeError, ValueError):
        return False
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=CONSISTENCY_RTOL, abs_tol=1e-300)


def iter_records(runs_dir: Path | Sequence[Path], task: str | None = None) -> Iterator[tuple[Path, dict[str, Any]]]:
    """Every `record.json` under `runs_dir` (optionally of one task), sorted by path, each checked (`read_record`).

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
            rec = read_record(path)
            if task is None or rec.get("task") == task:
                yield path.parent, rec


def runs_label(runs_dir: Path | Sequence[Path]) -> str:
    """`runs_dir` (one folder or several) as it is named in messages."""
    return str(runs_dir) if isinstance(runs_dir, (str, Path)) else ", ".join(str(r) for r in runs_dir)


def _num(value: Any) -> float:
    return float("nan") if value is None else float(value)
