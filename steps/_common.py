"""Small helpers shared by several steps (artifact conventions that span steps)."""

from __future__ import annotations

from pathlib import Path

from go_core import artifacts as art


def final_model(inputs: dict[str, Path]):
    """The Gaussians a downstream step should use and where they came from: the repaired set when the
    repair step produced one, else the coarse set. Returns (Gaussians, "repair" | "coarse")."""
    folder, used, _ = art.final_model(inputs["coarse"], inputs.get("repair"))
    return art.read_gaussians(folder), used


def write_skipped(ctx, artifact: art.Artifact, reason: str, **extra) -> None:
    """Finish a step honestly without doing its work: ``artifact`` says ``{"status": "skipped",
    "reason": ...}``, and the reason goes to the manifest (and so the report) and the log."""
    art.write_json(ctx.out_dir, artifact, {"status": art.STATUS_SKIPPED, "reason": reason, **extra})
    ctx.record(status="skipped", reason=reason)
    ctx.log.warning("%s skipped: %s", ctx.step, reason)


class ResumedProgress:
    """A step's progress bar, created at the first step that runs, so a resumed loop starts at its
    checkpoint: ``advance(step, **fields)`` per step, ``close()`` at the end."""

    def __init__(self, ctx, total: int, description: str) -> None:
        self.ctx, self.total, self.description = ctx, total, description
        self.bar = None

    def advance(self, step: int, **fields) -> None:
        if self.bar is None:
            self.bar = self.ctx.progress(self.total, self.description, completed=step - 1)
        self.bar.advance(1, **fields)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
