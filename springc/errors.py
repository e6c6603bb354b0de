"""User-facing errors and diagnostics with source positions.

A user error (bad netlist, bad data, bad option) is a `SpringcError`; the CLI prints
`format()` and exits 1. Anything else escaping to the CLI is an internal error.
"""

from __future__ import annotations

from dataclasses import dataclass

# Source texts registered by the parser so that diagnostics can quote the offending line.
_SOURCES: dict[str, list[str]] = {}


def register_source(filename: str, text: str) -> None:
    """Remember `text` under `filename` so diagnostics can show its lines with a caret."""
    _SOURCES[filename] = text.splitlines()


def source_line(filename: str, line: int) -> str | None:
    """The text of `line` (1-based) of a registered source, or None if unknown."""
    lines = _SOURCES.get(filename)
    if lines is None or not 1 <= line <= len(lines):
        return None
    return lines[line - 1]


@dataclass(frozen=True)
class SourceLoc:
    """Where something was written: file, 1-based line and column, and the instance path
    (`X1.X2`, empty at top level) through which it was elaborated."""

    file: str
    line: int
    col: int
    instance: str = ""

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


def _quote(loc: SourceLoc) -> str:
    text = source_line(loc.file, loc.line)
    if text is None:
        return ""
    gutter = f"{loc.line:5d} | "
    caret = " " * (len(gutter) - 2) + "| " + " " * max(loc.col - 1, 0) + "^"
    return f"\n{gutter}{text}\n{caret}"


@dataclass(frozen=True)
class Diagnostic:
    """One message from a check: severity is 'error', 'warning' or 'info'."""

    severity: str
    message: str
    loc: SourceLoc | None = None
    hint: str | None = None

    def format(self) -> str:
        """`file:line:col: severity: message`, the source line with a caret, and the hint."""
        head = f"{self.loc}: " if self.loc else ""
        where = ""
        if self.loc and self.loc.instance:
            where = f" (in instance {self.loc.instance})"
        text = f"{head}{self.severity}: {self.message}{where}"
        if self.loc:
            text += _quote(self.loc)
        if self.hint:
            text += f"\nhint: {self.hint}"
        return text


class SpringcError(Exception):
    """A user error. `format()` gives the full message; the CLI exits with status 1."""

    def __init__(
        self, message: str, loc: SourceLoc | None = None, hint: str | None = None
    ) -> None:
        super().__init__(message)
        self.diagnostic = Diagnostic("error", message, loc, hint)

    @property
    def message(self) -> str:
        return self.diagnostic.message

    @property
    def loc(self) -> SourceLoc | None:
        return self.diagnostic.loc

    def format(self) -> str:
        return self.diagnostic.format()


class NetlistError(SpringcError):
    """An error in a netlist: syntax, semantics or physics."""


class CheckError(NetlistError):
    """One or more failed checks; carries every error diagnostic found."""

    def __init__(self, diagnostics: list[Diagnostic]) -> None:
        first = diagnostics[0]
        super().__init__(first.message, first.loc, first.hint)
        self.diagnostics = diagnostics

    def format(self) -> str:
        return "\n".join(d.format() for d in self.diagnostics)


class DataError(SpringcError):
    """Bad input data (audio file, data set, array file): names the file and the reason."""

    def __init__(self, path: str, reason: str, hint: str | None = None) -> None:
        super().__init__(f"{path}: {reason}", None, hint)
        self.path = path
        self.reason = reason

    def format(self) -> str:
        text = f"error: {self.path}: {self.reason}"
        if self.diagnostic.hint:
            text += f"\nhint: {self.diagnostic.hint}"
        return text


class SimulationError(SpringcError):
    """A run that diverged or could not be carried out."""


class DivergedRuns(SimulationError):
    """Some runs of a kernel call diverged: `diverged` (their indices in the call) and the
    call's `reductions`, valid for every other run, so that only these need simulating
    again."""

    def __init__(self, message: str, diverged, reductions: dict, hint: str | None = None):
        super().__init__(message, hint=hint)
        self.diverged = diverged
        self.reductions = reductions


class UsageError(SpringcError):
    """A bad option or combination of options."""
