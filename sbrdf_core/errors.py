"""Exceptions with enough context to act on: a file, a line, the valid choices."""

from __future__ import annotations

from dataclasses import dataclass


class SbrdfError(Exception):
    """Base class of every error sbrdf raises on purpose."""


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a graph, located in its YAML file."""

    message: str
    file: str = "<graph>"
    line: int | None = None

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line is not None else self.file
        return f"{where}: {self.message}"


class GraphError(SbrdfError):
    """A graph failed validation; ``problems`` lists every problem found."""

    def __init__(self, problems: list[Problem]):
        self.problems = list(problems)
        n = len(self.problems)
        head = f"graph is invalid ({n} problem{'s' if n != 1 else ''}):"
        super().__init__("\n".join([head] + [f"  {p}" for p in self.problems]))


class ParameterError(SbrdfError):
    """A parameter value does not match its declaration."""


class PluginError(SbrdfError):
    """A plugin is unknown, broken or declares something inconsistent."""


class ArtifactError(SbrdfError):
    """An artifact is missing, incomplete or of the wrong kind."""


class RunError(SbrdfError):
    """Executing a graph failed; the artifacts written so far stay resumable."""
