"""User-facing errors: each carries one clear line naming the file (when there is one) and the problem."""

from __future__ import annotations

from pathlib import Path


class GoError(Exception):
    """Base of every error the CLI prints as one line without a traceback."""

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.message = message
        super().__init__(f"{path}: {message}" if path is not None else message)


class SceneError(GoError):
    """A scene folder, image, mask or camera is missing or malformed."""


class PipelineError(GoError):
    """pipeline.yaml or a --set/--profile choice is malformed."""


class MissingWeightsError(GoError):
    """A model needed by a step has no local weights; the message says what is missing and how to get it."""


class InvalidGaussiansError(GoError):
    """Gaussian parameters the rasterizer cannot render meaningfully (NaN/inf, or scales >= 1e20)."""


class CollapsedModelError(GoError):
    """Optimisation removed almost every Gaussian: the model cannot be the object (a wrong result)."""


class EmptyHullError(GoError):
    """The mask frusta do not intersect: the masks do not overlap, the poses are probably wrong."""


class PoseCheckError(GoError):
    """The pose check or SfM could not run (too few views, no matches, no reconstruction, ...)."""


def first_line(exc: BaseException) -> str:
    """The first non-empty line of an exception's message, or its type name when the message is empty
    (for one-line reports of errors raised by libraries)."""
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__
