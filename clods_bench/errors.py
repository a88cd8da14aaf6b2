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
