"""The one exception type the CLI turns into a clear message (no traceback unless --debug)."""

from __future__ import annotations


class ClodsError(Exception):
    """A user-facing error: says what is wrong and where (file, field, plugin name)."""

    def __init__(self, what: str, where: str | None = None, hint: str | None = None) -> None:
        self.what = what
        self.where = where
        self.hint = hint
        super().__init__(self.message)

    @property
    def message(self) -> str:
        text = self.what if self.where is None else f"{self.where}: {self.what}"
        if self.hint:
            text += f" ({self.hint})"
        return text


def closest(name: str, choices: list[str] | tuple[str, ...] | set[str]) -> str | None:
    """The closest known name to a misspelled one, for 'did you mean ...' hints."""
    import difflib

    found = difflib.get_close_matches(name, sorted(choices), n=1, cutoff=0.5)
    return found[0] if found else None


def unknown_name(kind: str, name: str, choices: list[str] | tuple[str, ...] | set[str]) -> ClodsError:
    """Build the error for an unknown plugin/scene/preset name, suggesting the closest known one."""
    best = closest(name, choices)
    hint = f"did you mean '{best}'?" if best else None
    known = ", ".join(sorted(choices)) or "none"
    return ClodsError(f"unknown {kind} '{name}'; known: {known}", hint=hint)


class PluginError(ClodsError):
    """A plugin raised while the benchmark called it: names the plugin, the stage (build, fit, rollout, render,
    predict) and the seed, with the plugin's own exception as the cause (`__cause__`)."""

    def __init__(self, kind: str, name: str, stage: str, error: str, message: str, seed: int | None = None, builtin: bool = False) -> None:
        self.kind, self.name, self.stage, self.error, self.detail, self.seed, self.builtin = kind, name, stage, error, message, seed, builtin
        context = f"stage: {stage}" + (f", seed {seed}" if seed is not None else "")
        super().__init__(f"{kind} '{name}' raised {error} during {stage} ({context})" + (f": {message}" if message else ""))

    def __reduce__(self) -> tuple:  # pickled from a worker process: rebuilt from its fields
        return (type(self), (self.kind, self.name, self.stage, self.error, self.detail, self.seed, self.builtin))


STAGE_ATTRIBUTE = "clods_stage"
"""Set on an exception (by `mark_stage`) to the innermost stage of the run it passed through, for the CLI's message."""


def mark_stage(exc: BaseException, stage: str) -> None:
    """Note on `exc` the stage it was raised in, unless an inner stage noted one already."""
    if getattr(exc, STAGE_ATTRIBUTE, None) is None:
        try:
            setattr(exc, STAGE_ATTRIBUTE, stage)
        except (AttributeError, TypeError):  # an exception type without a __dict__: its message stays unplaced
            pass


DISK_FULL_ERRNOS = ("ENOSPC", "EDQUOT")
NO_PERMISSION_ERRNOS = ("EACCES", "EPERM", "EROFS")


def environment_problem(exc: BaseException) -> tuple[str, str] | None:
    """(what failed, what to do) when `exc` is the environment's failure rather than a bug: a full disk or quota,
    a permission or read-only file system, memory (MemoryError, torch's 'not enough memory' / 'out of memory'), a
    worker process killed by the system; else None."""
    import errno

    text = str(exc)
    if isinstance(exc, MemoryError) or (isinstance(exc, RuntimeError) and ("not enough memory" in text or "out of memory" in text.lower())):
        detail = f" ({type(exc).__name__}: {text})" if text else ""
        return f"out of memory{detail}", "use a smaller config (data sizes, batch_size, latent_size) or a machine with more memory"
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, "")
        path = f": {exc.filename}" if exc.filename else ""
        if name in DISK_FULL_ERRNOS:
            return f"disk full ({exc.strerror or text}){path}", "free space or point runs_dir / data.root elsewhere, then rerun: finished work is kept"
        if name in NO_PERMISSION_ERRNOS:
            return f"{'read-only file system' if name == 'EROFS' else 'permission denied'}{path}", "make it writable or point runs_dir / data.root elsewhere"
    if type(exc).__name__ == "BrokenProcessPool":
        return ("a worker process ended abruptly (killed by the system, most often for lack of memory)",
                "use fewer --jobs or a smaller config, then rerun: finished work is kept")  # fmt: skip
    return None
