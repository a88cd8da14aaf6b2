"""Where independent jobs execute: in this process, in local worker processes (`--jobs N`) or as Ray tasks.

A job is any picklable item and a function applied to it (`map(fn, items, ...)`): a (run, seed) job (`SeedJob`, a
resolved `RunConfig` as a plain dict, so it pickles the same everywhere, and one seed; see `seed_jobs`) or one
trajectory of a dataset being generated. Every worker runs inside the exact scope unless host paths are asked for,
so the numbers do not depend on the executor or the number of workers.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Callable, Literal, Sequence

from rich.progress import Progress

from clods_bench import numerics
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import MAX_THREADS_ENV

ExecutorName = Literal["local", "ray"]
EXECUTORS: tuple[str, ...] = ("local", "ray")


@dataclass(frozen=True)
class SeedJob:
    """One seed of one run: the resolved config (a dict) and the seed."""

    config: dict[str, Any]
    seed: int
    name: str


@dataclass(frozen=True)
class InExactScope:
    """`fn(item)` inside the exact scope unless host paths are asked for: what a worker process runs (the scope is
    per process, and a worker is a fresh one)."""

    fn: Callable[[Any], Any]

    def __call__(self, item: Any) -> Any:
        with numerics.maybe_exact():
            return self.fn(item)


def _call_in_scope(fn: Callable[[Any], Any], item: Any) -> Any:
    """`InExactScope(fn)(item)` as a plain function (what a Ray task runs)."""
    return InExactScope(fn)(item)


def _die_with_parent(parent: int) -> None:
    """Linux: have the kernel send this worker SIGTERM when the process that started it dies, even by SIGKILL, so a
    killed `reproduce` leaves no worker computing on alone (its writes are atomic and its locks are `flock`s, which
    die with it). Elsewhere a no-op."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - no libc prctl
        return
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def default_jobs() -> int:
    """Worker processes when --jobs is not given: one per core this process may run on (the numbers do not depend on
    the count: each job runs at the exact scope's thread count, alone in its process)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def worker_threads(jobs: int) -> int:
    """Threads of each of `jobs` parallel workers: deterministic mode's fixed count (the numbers depend on it), else
    the cores shared out, max(1, cores // jobs)."""
    if numerics.requested():
        return numerics.threads()
    return max(1, (os.cpu_count() or 1) // int(jobs))


def _init_worker(threads: int, parent: int | None = None) -> None:
    """Start of a parallel worker process: die with its parent (`_die_with_parent`), cap torch's threads (every later
    setting too, see `clods_bench.numerics.thread_limits`) and numba's parallel kernels (the splatting backend) at `threads`."""
    if parent is not None:
        _die_with_parent(parent)
    os.environ[MAX_THREADS_ENV] = str(threads)
    os.environ["OMP_NUM_THREADS"] = os.environ["NUMBA_NUM_THREADS"] = str(threads)
    import numba
    import torch

    torch.set_num_threads(threads)
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


class LocalExecutor:
    """Runs jobs locally: one after another in this process (`jobs=1`), or in `jobs` worker processes.

    With k > 1 workers on c cores each worker's torch threads are capped at max(1, c // k): the jobs
    share the cores instead of oversubscribing them. Jobs that need the same cached result (a stage-1
    fit, an extraction, a simulator fit) wait for each other through file locks, so nothing is computed twice.
    """

    name = "local"

    def __init__(self, jobs: int = 1) -> None:
        if int(jobs) < 1:
            raise ClodsError(f"must be >= 1, got {jobs}", where="--jobs")
        self.jobs = int(jobs)

    def map(
        self,
        fn: Callable[[Any], Any],
        items: Sequence[Any],
        describe: Callable[[Any], str] = str,
        progress: bool = True,
        deadline: float | None = None,
    ) -> list[Any]:
        """`[fn(item) for item in items]` (results in item order), with a progress bar.

        `deadline` (a `time.monotonic()` value): items not started by then are not started at all and their result is
        None; started ones run to the end (a time-boxed `reproduce --budget`). Items start in list order either way.
        """
        if self.jobs == 1 or len(items) <= 1:
            out: list[Any] = [None] * len(items)
            with Progress(disable=not progress) as bar:
                task = bar.add_task("jobs (local)", total=len(items))
                for i, item in enumerate(items):
                    if _past(deadline):
                        break
                    bar.update(task, description=f"job {describe(item)}")
                    out[i] = fn(item)
                    bar.advance(task)
            return out
        threads = worker_threads(self.jobs)
        results: list[Any] = [None] * len(items)
        ctx = multiprocessing.get_context("spawn")  # a fresh interpreter per worker: no forked torch/numba state
        pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx, initializer=_init_worker, initargs=(threads, os.getpid()))
        with _term_as_interrupt():
            try:
                # At most `jobs` submitted at a time, the next one when a worker is free: a job that would wait in the
                # pool's queue past the deadline is never submitted.
                queue = iter(enumerate(items))
                running: dict[Any, int] = {}

                def submit_next() -> None:
                    if _past(deadline):
                        return
                    nxt = next(queue, None)
                    if nxt is not None:
                        running[pool.submit(InExactScope(fn), nxt[1])] = nxt[0]

                for _ in range(self.jobs):
                    submit_next()
                with Progress(disable=not progress) as bar:
                    task = bar.add_task(f"jobs (local, {self.jobs} processes x {threads} threads)", total=len(items))
                    while running:
                        done, _pending = wait(running, return_when=FIRST_COMPLETED)
                        for fut in done:
                            results[running.pop(fut)] = fut.result()
                            bar.advance(task)
                            submit_next()
            except Exception:  # a failed job: drop the queued ones, let the running ones finish and save their work
                pool.shutdown(wait=True, cancel_futures=True)
                raise
            except BaseException:  # Ctrl-C, SIGTERM: stop now
                stop_workers(pool)
                raise
        pool.shutdown(wait=True)
        return results


def _past(deadline: float | None) -> bool:
    """Whether the monotonic clock has passed `deadline` (never, for None)."""
    return deadline is not None and time.monotonic() >= deadline


def stop_workers(pool: ProcessPoolExecutor, grace: float = 5.0) -> None:
    """Stop a process pool now: cancel its queued jobs and terminate its workers, running jobs included (an interrupted
    job resumes from what it wrote: checkpoints, caches and records are written atomically). Waiting for the running
    jobs instead, as `shutdown` does, kept an interrupted `reproduce` alive for as long as its longest job."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    deadline = time.monotonic() + grace
    for proc in procs:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.kill()
            proc.join(1.0)


class _term_as_interrupt:
    """While active (main thread only), SIGTERM raises KeyboardInterrupt like Ctrl-C, so `kill <pid>` and a scheduler's
    timeout stop the workers and end with the CLI's 'interrupted' message instead of leaving the workers running."""

    def __enter__(self) -> "_term_as_interrupt":
        self.installed, self.previous = False, None
        if threading.current_thread() is threading.main_thread():
            self.previous, self.installed = signal.signal(signal.SIGTERM, _raise_interrupt), True
        return self

    def __exit__(self, *exc: object) -> None:
        if self.installed:  # None: the previous handler was not set from Python, so restore the default
            signal.signal(signal.SIGTERM, signal.SIG_DFL if self.previous is None else self.previous)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


class RayExecutor:
    """Runs jobs as Ray tasks: on an existing cluster (`address`), the one this process joined, or a local one it starts.

    Each task asks for `cpus_per_task` CPUs; a job that uses CUDA (`job_uses_gpu`) also asks for `gpu_share` of a GPU
    when the cluster has GPUs (default $CLODS_BENCH_RAY_GPU_SHARE or 0.25), so CPU and GPU jobs pack onto one machine.
    """

    name = "ray"

    def __init__(self, address: str | None = None, cpus_per_task: float = 1.0, num_cpus: int | None = None,
                 gpu_share: float | None = None) -> None:  # fmt: skip
        self.address = address
        self.cpus_per_task = cpus_per_task
        self.num_cpus = num_cpus
        self.gpu_share = gpu_share_from_env() if gpu_share is None else float(gpu_share)

    def _ray(self) -> Any:
        try:
            import ray
        except ImportError:
            raise ClodsError(
                "the Ray executor needs the 'ray' package", where="--executor ray", hint="pip install 'clods-bench[ray]' (or: pip install ray)"
            ) from None
        return ray

    def map(
        self, fn: Callable[[Any], Any], items: Sequence[Any], describe: Callable[[Any], str] = str, progress: bool = True, deadline: float | None = None
    ) -> list[Any]:
        """Submit `fn(item)` for every item as a Ray task and return the results in item order (no `deadline`: Ray
        schedules every task at once)."""
        if deadline is not None:
            raise ClodsError("a time budget needs the local executor (Ray schedules every job at once)", where="--budget")
        ray = self._ray()
        started = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"address": self.address} if self.address else {"num_cpus": self.num_cpus}
            ray.init(log_to_driver=False, include_dashboard=False, **kwargs)
            started = True
        try:
            has_gpu = ray.cluster_resources().get("GPU", 0) > 0
            remote = ray.remote(num_cpus=self.cpus_per_task, num_gpus=0, max_retries=0)(_call_in_scope)
            shares = [self.gpu_share if has_gpu and job_uses_gpu(item) else 0.0 for item in items]
            refs = [remote.options(num_gpus=share).remote(fn, item) if share else remote.remote(fn, item) for item, share in zip(items, shares)]
            gpus = f"{sum(1 for x in shares if x)} of them on a GPU share of {self.gpu_share:g}" if has_gpu else "no GPU"
            index = {ref: i for i, ref in enumerate(refs)}
            out: list[Any] = [None] * len(refs)
            pending = list(refs)
            with Progress(disable=not progress) as bar:
                task = bar.add_task(f"jobs (ray, {gpus})", total=len(refs))
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    for ref in done:
                        try:
                            out[index[ref]] = ray.get(ref)
                        except ray.exceptions.RayTaskError as exc:
                            cause = exc.as_instanceof_cause()
                            if isinstance(cause, ClodsError):
                                raise ClodsError(cause.what, where=cause.where, hint=cause.hint) from None
                            raise ClodsError(f"Ray task failed: {exc}", where=f"job {describe(items[index[ref]])}") from None
                        bar.advance(task)
            return out
        finally:
            if started:
                ray.shutdown()


GPU_SHARE_ENV = "CLODS_BENCH_RAY_GPU_SHARE"
GPU_SHARE_DEFAULT = 0.25  # a GPU job asks Ray for this much of one GPU: 4 of them share a GPU at once


def gpu_share_from_env() -> float:
    """The GPU share of a GPU job under Ray: $CLODS_BENCH_RAY_GPU_SHARE (0 < share <= 1), else GPU_SHARE_DEFAULT."""
    raw = os.environ.get(GPU_SHARE_ENV)
    if raw is None:
        return GPU_SHARE_DEFAULT
    try:
        share = float(raw)
    except ValueError:
        share = float("nan")
    if not 0.0 < share <= 1.0:
        raise ClodsError(f"must be a number in (0, 1], got {raw!r}", where=f"${GPU_SHARE_ENV}")
    return share


def job_uses_gpu(item: Any) -> bool:
    """Whether a (run, seed) job asks for CUDA: its renderer with device 'cuda' or backend 'gsplat', its simulator or
    video predictor with device 'cuda[:N]', or a stage-0 surfel fit on 'gsplat' (only the plugins the run names
    count: an override for every run of a plan sets options of plugins most runs never build). Under Ray only these
    get a GPU share; the others (physics, CPU simulators, renderers and predictors) take none and run beside them
    on the other cores."""
    if not isinstance(item, SeedJob):
        return False
    cfg = item.config

    def opts(section: str, plugin: str) -> dict[str, Any]:
        got = (cfg.get(section) or {}).get(cfg.get(plugin) or "")
        return got if isinstance(got, dict) else {}

    renderer = opts("renderer_config", "renderer")
    if renderer.get("device") == "cuda" or renderer.get("backend") == "gsplat":
        return True
    if any(str(opts(section, plugin).get("device", "cpu")).startswith("cuda") for section, plugin in
           (("sim_config", "sim"), ("video_config", "predictor"))):  # fmt: skip
        return True
    task = cfg.get("task_config") or {}
    stage0 = [task.get("initial_mesh") or {}, (task.get("clods") or {}).get("stage0") or {}]
    return any(isinstance(o, dict) and o.get("backend") == "gsplat" for o in stage0)


def make_executor(name: str, address: str | None = None, jobs: int = 1) -> LocalExecutor | RayExecutor:
    """The executor called `name` ('local', with `jobs` worker processes, or 'ray')."""
    if name == "local":
        return LocalExecutor(jobs)
    if name == "ray":
        return RayExecutor(address=address)
    raise ClodsError(f"unknown executor '{name}'", where="--executor", hint=f"one of {', '.join(EXECUTORS)}")
