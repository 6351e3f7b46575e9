"""A work dir that remembers: the profile, ``--set`` overrides and seed of the last run, in
``<workdir>/params.yaml`` (human-readable, like DVC's params.yaml).

``status``, ``report`` and a plain ``run`` use them; flags given on the command line change them
(``--profile`` and ``--seed`` replace, ``--set`` adds to the remembered overrides, ``--reset-params``
starts from pipeline.yaml's defaults), and ``describe_changes`` says what a change does before it runs.
Cheap (yaml only), so a no-op run stays fast.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from go_core.errors import PipelineError

PARAMS_FILE = "params.yaml"
HEADER = """\
# go-pipeline: the settings of the last `go-pipeline run` in this work dir. `go-pipeline status`, `report`
# and a plain `run` use them; `run --profile/--set/--seed` change them, `run --reset-params` forgets them.
# You may edit `profile`, `seed` and `set` by hand. `effective` is for reading only: every param whose
# resolved value differs from pipeline.yaml's default.
"""


@dataclass
class Settings:
    """What a run is asked for beyond pipeline.yaml: a profile, dotted overrides and a seed."""

    profile: str | None = None
    sets: dict[str, Any] = field(default_factory=dict)  # {"coarse.iterations": 500}
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"profile": self.profile, "seed": self.seed, "set": dict(self.sets)}


def params_path(workdir: Path) -> Path:
    return Path(workdir) / PARAMS_FILE


def load_settings(workdir: Path) -> Settings | None:
    """The remembered settings of a work dir, or None when it has none (never run)."""
    import yaml

    path = params_path(workdir)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, yaml.YAMLError) as e:
        raise PipelineError(
            f"cannot read the remembered settings ({e}); fix or delete the file", path
        ) from None
    if not isinstance(data, dict):
        raise PipelineError("expected a mapping with profile / seed / set", path)
    profile, seed, sets = data.get("profile"), data.get("seed", 0), data.get("set") or {}
    if profile is not None and not isinstance(profile, str):
        raise PipelineError(f"profile must be a name or null, got {profile!r}", path)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise PipelineError(f"seed must be an integer, got {seed!r}", path)
    if not isinstance(sets, dict):
        raise PipelineError("set must map STEP.PARAM -> value", path)
    from go_pipeline.pipeline import flatten_overrides

    return Settings(profile, {str(k): v for k, v in flatten_overrides(sets).items()}, seed)


def merge(
    saved: Settings | None,
    profile: str | None,
    sets: dict[str, Any],
    seed: int | None,
    reset: bool = False,
    default_profile: str | None = None,
) -> Settings:
    """The settings of this invocation: the remembered ones (unless ``reset``) changed by the flags given
    (None = not given). ``default_profile`` applies when neither a flag nor the work dir names a profile."""
    base = Settings() if (saved is None or reset) else saved
    chosen_profile = profile if profile is not None else (base.profile or default_profile)
    merged_sets = {**base.sets, **sets}  # --set adds to (or replaces one of) the remembered overrides
    return Settings(chosen_profile, merged_sets, base.seed if seed is None else int(seed))


def effective_params(pipeline, settings: Settings) -> dict[str, dict[str, Any]]:
    """The resolved params of every step under ``settings``."""
    return pipeline.resolve_params(settings.profile, settings.sets)


def non_default(pipeline, settings: Settings) -> dict[str, dict[str, Any]]:
    """{step: {param: value}} for each resolved param that differs from pipeline.yaml's default."""
    defaults = pipeline.resolve_params(None, None)
    resolved = effective_params(pipeline, settings)
    out: dict[str, dict[str, Any]] = {}
    for step, values in resolved.items():
        for name, value in values.items():
            if defaults[step].get(name) != value:
                out.setdefault(step, {})[name] = value
    return out


def describe_changes(pipeline, old: Settings | None, new: Settings, limit: int = 8) -> list[str]:
    """Lines saying what changes from the remembered settings to ``new`` (empty when nothing does)."""
    if old is None:
        return []
    lines: list[str] = []
    if old.profile != new.profile:
        lines.append(f"profile {old.profile or '(none)'} -> {new.profile or '(none)'}")
    if old.seed != new.seed:
        lines.append(f"seed {old.seed} -> {new.seed} (every step reruns)")
    before, after = effective_params(pipeline, old), effective_params(pipeline, new)
    changed = [
        (f"{step}.{name}", before[step].get(name), value)
        for step, values in after.items()
        for name, value in values.items()
        if before.get(step, {}).get(name) != value
    ]
    for dotted, a, b in changed[:limit]:
        lines.append(f"{dotted} {a!r} -> {b!r}")
    if len(changed) > limit:
        lines.append(f"... and {len(changed) - limit} more params")
    if changed:
        steps = sorted({d.split(".")[0] for d, _, _ in changed}, key=pipeline.order.index)
        lines.append("reruns " + ", ".join(steps) + " and the steps after them")
    return lines


def save_settings(workdir: Path, pipeline, settings: Settings) -> Path:
    """Write ``<workdir>/params.yaml`` atomically (only when its content changes)."""
    import yaml

    from go_core.io.atomic import atomic_write_text, readable

    body = settings.to_dict()
    body["effective"] = non_default(pipeline, settings)
    text = HEADER + yaml.safe_dump(body, sort_keys=False, default_flow_style=False, width=110)
    path = params_path(workdir)
    try:
        if path.read_text(encoding="utf-8") == text:
            return path
    except OSError:
        pass
    return readable(atomic_write_text(path, text))
