"""The DAG runner: run the stale steps of pipeline.yaml for one scene, in topological order, caching every
artifact under its content-derived key; and ``pipeline_status`` (fresh / stale / missing and why).

See docs/runner.md for the key, the work dir layout and the manifest.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from go_core.errors import GoError, PipelineError, SceneError
from go_pipeline import store
from go_pipeline.codehash import CodeFingerprint, changed_files, fingerprint
from go_pipeline.hashing import FileHashCache, cache_key, combine_file_hashes, folder_hashes
from go_pipeline.pipeline import (
    SCENE_INPUT,
    Pipeline,
    StepRules,
    StepSpec,
    ignored_overrides,
    load_pipeline,
    require_installed_steps,
    step_rules,
)

MAX_LOGS = 50


class StepFailed(GoError):
    """A step raised or its process died; the message names the step and the run log."""

    exit_code = 1


def resume_note(checkpoint_dir: Path) -> str | None:
    """What a step resumes from when an earlier, killed run left checkpoints for its key ("checkpoint 1000
    (checkpoints/coarse/<key>)"), or None. The number is the newest checkpoint file's (ckpt_0001000.pt)."""
    import re

    found = (
        [p for p in Path(checkpoint_dir).rglob("*") if p.is_file()] if Path(checkpoint_dir).is_dir() else []
    )
    if not found:
        return None
    newest = max(found, key=lambda p: (p.stat().st_mtime, p.name))
    number = re.findall(r"\d+", newest.stem)
    where = f"{checkpoint_dir.parent.parent.name}/{checkpoint_dir.parent.name}/{checkpoint_dir.name[:12]}"
    return f"checkpoint {int(number[-1])} ({where})" if number else f"its checkpoints ({where})"


def _build_note(results: list[StepResult]) -> str:
    """What part of a run's wall time was the one-time rasterizer compile (in no step's time)."""
    build = sum(float(r.record.get("rasterizer_build_s", 0.0)) for r in results if not r.cached)
    return f", of which {build:.0f} s the one-time compile of the CPU rasterizer" if build >= 0.5 else ""


@dataclass
class StepResult:
    name: str
    status: str  # "ran" | "cached" | "skipped" (ran or cached, and the step recorded status "skipped")
    key: str
    artifact_dir: Path
    cached: bool
    wall_s: float  # this run's time for the step (0 when cached); the manifest keeps the original timing
    record: dict[str, Any] = field(default_factory=dict)


@dataclass
class RunSummary:
    scene_dir: Path
    workdir: Path
    profile: str | None
    seed: int
    steps: list[StepResult]
    log_path: Path | None  # None when nothing ran (a no-op run writes no log)
    started: str
    finished: str
    wall_s: float
    overrides: dict[str, Any] = field(default_factory=dict)  # the --set values ({"step.param": value})
    status: str = "finished"  # "interrupted" / "failed": the run stopped before its end (history only)

    def step(self, name: str) -> StepResult:
        for s in self.steps:
            if s.name == name:
                return s
        raise KeyError(name)

    @property
    def ran(self) -> list[str]:
        return [s.name for s in self.steps if not s.cached]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["scene_dir"], d["workdir"], d["log_path"] = (
            str(self.scene_dir),
            str(self.workdir),
            str(self.log_path) if self.log_path is not None else None,
        )
        for s in d["steps"]:
            s["artifact_dir"] = str(s["artifact_dir"])
        return d


@dataclass
class StatusRow:
    step: str
    state: str  # "fresh" | "stale" | "missing"
    reason: str
    key: str | None


# ---------------------------------------------------------------------------------------------- planning
@dataclass
class _Plan:
    pipeline: Pipeline
    params: dict[str, dict[str, Any]]
    rules: dict[str, StepRules]  # each step's version override and skip rules
    code: dict[str, CodeFingerprint]  # the source files each step runs
    scene_dir: Path
    workdir: Path
    seed: int
    verify: bool = False  # full content-hash check of every cached artifact (else sizes only)
    allow_outside: bool = False  # the scene may name files outside its folder
    hash_cache: FileHashCache | None = None  # per-file sha256 cache (scene files, model files)
    external: dict[str, dict[str, Any]] = field(default_factory=dict)  # step -> external_inputs(...)
    verified: set[Path] = field(default_factory=set)  # artifacts whose files matched their sha256 this run
    recomputed: dict[str, StepResult] = field(default_factory=dict)  # damaged upstreams rerun mid-run
    profile: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)  # --set values, flat ("step.param": value)


def _plan(
    scene_dir: str | Path,
    workdir: str | Path | None,
    profile: str | None,
    overrides: dict[str, Any] | None,
    seed: int,
    pipeline: Pipeline | str | Path | None,
    steps: Iterable[str] | None = None,
    allow_custom_steps: bool | None = None,
) -> _Plan:
    """Everything a run or ``status`` decides before touching the work dir: resolved params, each step's
    rules and code. ``pipeline``: the loaded pipeline (a run loads it once), or its file (None: packaged)."""
    scene = Path(scene_dir).resolve()
    if not scene.is_dir():
        raise SceneError("scene folder not found" if not scene.exists() else "not a folder", scene)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise PipelineError(f"seed must be an integer, got {seed!r}", "--seed")
    if not isinstance(pipeline, Pipeline):
        pipeline = load_pipeline(pipeline)
    require_installed_steps(pipeline, allow_custom_steps)
    params = pipeline.resolve_params(profile, overrides)
    names = list(pipeline.steps) if steps is None else list(steps)
    rules = {n: step_rules(pipeline.steps[n], pipeline.path) for n in names}
    code = {n: fingerprint(pipeline.steps[n].module) for n in names}
    from go_pipeline.pipeline import flatten_overrides

    plan = _Plan(pipeline, params, rules, code, scene, store.workdir_for(scene, workdir), int(seed))
    plan.profile, plan.overrides = profile, flatten_overrides(overrides or {})
    return plan


def _scene_hash(plan: _Plan, cache_writable: bool) -> str:
    """Content hash of the scene: every file under the scene folder (through symlinks) and every file its
    format files name (images, masks), wherever it lives. A named file outside the folder is an error
    unless ``allow_outside``; then it is hashed under its absolute path."""
    cache = _hash_cache(plan)
    hashes = folder_hashes(
        plan.scene_dir, exclude=[plan.scene_dir / store.WORKDIR_NAME, plan.workdir], cache=cache
    )
    if not hashes:
        raise SceneError("scene folder is empty", plan.scene_dir)
    for named in _named_scene_files(plan.scene_dir):
        lexical = Path(os.path.normpath(os.path.join(plan.scene_dir, named)))
        try:
            rel = lexical.relative_to(plan.scene_dir).as_posix()
        except ValueError:
            rel = None
        if rel is not None and not rel.startswith(store.WORKDIR_NAME + "/"):
            if rel not in hashes and lexical.is_file():
                hashes[rel] = cache.file_hash(lexical)
            continue
        if not plan.allow_outside:
            raise SceneError(
                f"the scene names a file outside its folder: {named} (an absolute or '../' path); "
                "pass --allow-outside to read it (it is then part of the cache key)",
                plan.scene_dir,
            )
        if lexical.is_file():
            hashes["@outside" + lexical.as_posix()] = cache.file_hash(lexical)
    if cache_writable:
        cache.save()
    return combine_file_hashes(hashes)


def _named_scene_files(scene_dir: Path) -> list[Path]:
    """The files a scene's format files name (go_core.scene.loader.scene_input_files); a folder without
    format files (not a scene the packaged reader knows) names none, and costs no numpy import."""
    known = ("transforms_train.json", "transforms_test.json", "sparse")
    if not any((scene_dir / name).exists() for name in known):
        return []
    from go_core.scene.loader import scene_input_files

    return scene_input_files(scene_dir)


def _hash_cache(plan: _Plan) -> FileHashCache:
    if plan.hash_cache is None:
        plan.hash_cache = FileHashCache(plan.workdir / "cache" / "file_hashes.json")
    return plan.hash_cache


def _external(plan: _Plan, name: str) -> dict[str, Any]:
    """Library versions, model files and LPIPS weights the step reads (go_pipeline.external), once."""
    from go_pipeline.external import external_inputs

    if name not in plan.external:
        plan.external[name] = external_inputs(plan.params[name], _hash_cache(plan))
    return plan.external[name]


def _input_hashes(
    spec: StepSpec, scene_hash: str | None, done: dict[str, dict[str, Any]], scene_dir: Path
) -> dict[str, dict[str, Any]] | None:
    """name -> {step, key, content_hash} for every input, or None when an upstream has no artifact."""
    result: dict[str, dict[str, Any]] = {}
    for name, up in spec.inputs.items():
        if up == SCENE_INPUT:
            assert scene_hash is not None
            result[name] = {"step": None, "key": None, "content_hash": scene_hash, "path": str(scene_dir)}
        elif up in done:
            result[name] = {"step": up, "key": done[up]["key"], "content_hash": done[up]["content_hash"]}
        else:
            return None
    return result


def _gate_status(manifest: dict[str, Any]) -> str:
    """What a gate input puts in a key: whether its step ran, or skipped and why (not its content)."""
    record = manifest.get("record") or {}
    if record.get("status") == "skipped":
        return json.dumps({"status": "skipped", "reason": record.get("reason")}, sort_keys=True)
    return json.dumps({"status": "ran"})


def _key_for(
    plan: _Plan, name: str, inputs: dict[str, dict[str, Any]], done: dict[str, dict[str, Any]]
) -> str:
    from go_pipeline.skipping import foreign_params

    params = plan.params[name]
    foreign = foreign_params(plan.rules[name].skip_if_param, plan.params)
    if foreign:  # another step's param decides whether this step skips: part of its key
        params = {**params, "_skip_if_param": foreign}
    gates = plan.rules[name].gate_inputs  # only their status decides the step's work: it alone is keyed
    return cache_key(
        name,
        plan.rules[name].version,
        params,
        plan.seed,
        {k: _gate_status(done[v["step"]]) if k in gates else v["content_hash"] for k, v in inputs.items()},
        code=plan.code[name].digest,
        function=plan.pipeline.steps[name].function,
        external=_external(plan, name),
    )


# ---------------------------------------------------------------------------------------------- running
@dataclass(frozen=True)
class RunOptions:
    """How a run executes (nothing here is part of a cache key)."""

    device: str = "auto"  # auto | cpu | cuda
    in_process: bool = False  # run steps in this process (tests, debugging) instead of a worker each
    quiet: bool = False
    debug: bool = False  # a failed step's traceback on the terminal
    on_start: Callable[[Path], None] | None = None  # called with the work dir once it is locked


@dataclass(frozen=True)
class _Selection:
    steps: list[str]  # what runs, in run order
    force: frozenset[str]  # rerun even when cached
    until: str | None


@dataclass
class _Run:
    """One run while the work dir's lock is held: what its steps share."""

    plan: _Plan
    options: RunOptions
    display: Any  # go_pipeline.display.Display
    lock_fd: int | None
    scene_hash: str | None = None
    done: dict[str, dict[str, Any]] = field(default_factory=dict)  # step -> the manifest of its artifact
    results: list[StepResult] = field(default_factory=list)  # so far (an unfinished run's record)


def run_pipeline(
    scene_dir: str | Path,
    *,
    workdir: str | Path | None = None,
    profile: str | None = None,
    overrides: dict[str, Any] | None = None,
    until: str | None = None,
    force: Iterable[str] = (),
    seed: int = 0,
    pipeline_path: str | Path | None = None,
    device: str = "auto",
    in_process: bool = False,
    quiet: bool = False,
    debug: bool = False,
    on_start: Callable[[Path], None] | None = None,
    allow_custom_steps: bool | None = None,
    verify: bool = False,
    allow_outside: bool = False,
) -> RunSummary:
    """Run every stale step (up to ``until``) for one scene and return what happened to each step.

    ``overrides``: {"step.param": value} or {step: {param: value}}, applied after ``profile``.
    ``force``: steps to rerun even when cached (their descendants rerun only if the output changes).
    ``on_start(workdir)``: called once the work dir is locked, before any step (the CLI records the run's
    settings there).
    ``verify``: check every cached artifact's files against their sha256 (always: their sizes; and the
    full hash of each artifact a running step reads). A damaged artifact is recomputed.
    ``allow_outside``: the scene may name image/mask files outside its folder (hashed into the key).
    ``allow_custom_steps``: run step functions outside go_pipeline.steps (a pipeline file is code; None:
    the GO_ALLOW_CUSTOM_STEPS environment variable decides).
    Raises GoError subclasses (PipelineError, SceneError, LockedError, StepFailed, a step's own GoError).
    """
    pipeline = load_pipeline(pipeline_path)  # the one load of this run
    require_installed_steps(pipeline, allow_custom_steps)
    selection = _select(pipeline, until, force)
    options = RunOptions(device, in_process, quiet, debug, on_start)
    if device not in ("auto", "cpu", "cuda"):
        raise PipelineError(f"--device must be auto, cpu or cuda, got {device!r}")
    if device == "cuda":
        require_cuda()
    plan = _plan(scene_dir, workdir, profile, overrides, seed, pipeline, selection.steps, allow_custom_steps)
    plan.verify = bool(verify)
    plan.allow_outside = bool(allow_outside)

    from go_pipeline.lock import WorkdirLock

    created = not plan.workdir.exists()
    _require_writable(plan.workdir)
    try:
        with WorkdirLock(plan.workdir) as lock:
            return _run_locked(plan, selection, options, lock.fd)
    except GoError as e:
        # a first run refused by its input (not a step crash, whose traceback is in the log) leaves no
        # .go/ behind in the scene folder
        if created and not isinstance(e, StepFailed) and not _has_artifacts(plan.workdir):
            shutil.rmtree(plan.workdir, ignore_errors=True)
        raise


def _select(pipeline: Pipeline, until: str | None, force: Iterable[str]) -> _Selection:
    """The steps a run considers (``until`` and its ancestors, else all) and the forced ones, checked."""
    if until is not None:
        pipeline.require_step(until, "--until", from_file=False)
        wanted = pipeline.ancestors(until) | {until}
        steps = [n for n in pipeline.order if n in wanted]
    else:
        steps = pipeline.order
    for f in sorted(set(force)):
        pipeline.require_step(f, "--force", from_file=False)
    return _Selection(steps, frozenset(force), until)


def _require_writable(workdir: Path) -> None:
    try:
        workdir.mkdir(parents=True, exist_ok=True)
        probe = workdir / ".write-test"
        probe.touch()
        probe.unlink()
    except OSError as e:
        raise GoError(
            f"cannot write the work dir ({e.strerror or e}); choose one with --workdir", workdir
        ) from None


def _has_artifacts(workdir: Path) -> bool:
    root = workdir / "artifacts"
    return root.is_dir() and any(store.complete_artifacts(workdir, p.name) for p in root.iterdir())


def require_cuda() -> None:
    """``--device cuda`` is an error (not a silent CPU run) when torch sees no CUDA device."""
    import torch

    if not torch.cuda.is_available():
        why = "torch was built without CUDA" if torch.version.cuda is None else "no CUDA device is visible"
        raise PipelineError(
            f"--device cuda: CUDA is not available ({why}; torch {torch.__version__}); "
            "use --device cpu or --device auto"
        )


def _run_locked(plan: _Plan, selection: _Selection, options: RunOptions, lock_fd: int | None) -> RunSummary:
    """The body of ``run_pipeline`` while the work dir's lock is held."""
    from go_pipeline.display import Display

    started, t0 = _utc_now(), time.perf_counter()
    display = Display(_new_log_path(plan.workdir), quiet=options.quiet, debug=options.debug)
    run = _Run(plan, options, display, lock_fd)
    try:
        display.log.debug(
            f"go-pipeline run {plan.scene_dir} workdir={plan.workdir} profile={plan.profile} "
            f"seed={plan.seed} until={selection.until} force={sorted(selection.force)} "
            f"pipeline={plan.pipeline.path} python={sys.executable}"
        )
        for line in ignored_overrides(plan.pipeline, plan.params, plan.overrides):
            display.log.warning(line)
        store.check_scene_binding(plan.workdir, plan.scene_dir, bind=True)
        store.sweep_leftovers(plan.workdir)
        if options.on_start is not None:
            options.on_start(plan.workdir)
        steps = plan.pipeline.steps
        needs_scene = any(up == SCENE_INPUT for n in selection.steps for up in steps[n].inputs.values())
        run.scene_hash = _scene_hash(plan, cache_writable=True) if needs_scene else None
        for name in selection.steps:
            run.results.append(_run_one(run, name, name in selection.force))
        results = run.results
        results = [plan.recomputed.get(r.name, r) for r in results]
        _hash_cache(plan).save()  # model-file hashes found while keying the steps
        summary = RunSummary(
            plan.scene_dir, plan.workdir, plan.profile, plan.seed, results, display.log_file, started,
            _utc_now(), time.perf_counter() - t0, dict(plan.overrides),
        )  # fmt: skip
        _write_summary(plan.workdir, summary)
        ran, note = len(summary.ran), _build_note(results)
        display.log.info(
            f"done: {ran} step(s) ran, {len(results) - ran} cached ({summary.wall_s:.1f} s{note})"
            if ran
            else f"everything is up to date ({len(results)} steps cached, {summary.wall_s:.1f} s)"
        )
        return summary
    except BaseException as e:
        display.open_log()
        display.log.debug(f"run failed: {type(e).__name__}: {e}")  # the log file only
        status = "interrupted" if isinstance(e, (KeyboardInterrupt, SystemExit)) else "failed"
        _record_unfinished(run, started, t0, status)
        raise
    finally:
        display.close()


def _run_one(run: _Run, name: str, forced: bool) -> StepResult:
    """One step: reuse its cached artifact, else (after checking what it reads) skip or launch it, and
    commit what it wrote under its key."""
    plan, spec = run.plan, run.plan.pipeline.steps[name]
    while True:  # again when a damaged upstream was recomputed: its content (so this key) may differ
        inputs = _input_hashes(spec, run.scene_hash, run.done, plan.scene_dir)
        assert inputs is not None  # topological order: every upstream is in `done`
        key = _key_for(plan, name, inputs, run.done)
        run.display.current_step = name
        cached = _reuse(run, name, key, forced)
        if cached is not None:
            return cached
        run.display.open_log()
        if not _verify_inputs(run, spec):
            break
    skip = _runner_skip(run, name)
    if skip is None:
        run.display.log.info(f"  {name:<12} running  {key[:12]} ...")
        resumed = resume_note(store.checkpoint_path(plan.workdir, name, key))
        if resumed:
            run.display.log.info(f"  {name:<12} resuming from {resumed}")
    tmp, ckpt = _work_dirs(plan, name, key)
    started = _utc_now()
    result = _launch(run, name, _job(run, name, inputs, tmp, ckpt), skip)
    final = _commit(run, name, key, inputs, tmp, result, started)
    shutil.rmtree(ckpt, ignore_errors=True)
    _remove_if_empty(ckpt.parent)
    _log_result(run, name, key, result, ran_worker=skip is None)
    status = "skipped" if result.records.get("status") == "skipped" else "ran"
    return StepResult(name, status, key, final, False, result.wall_s, result.records)


def _reuse(run: _Run, name: str, key: str, forced: bool) -> StepResult | None:
    """The step's complete artifact for ``key``, taken from the cache (None: it must run; a damaged one
    is said and recomputed)."""
    plan = run.plan
    final = store.artifact_path(plan.workdir, name, key)
    manifest, problem = (
        (None, None) if forced else _check_artifact(final, plan.pipeline.steps[name], plan.verify)
    )
    if problem is not None:
        run.display.log.warning(f"  {name:<12} damaged  {key[:12]} ({problem}); recomputing")
    if manifest is None:
        return None
    if plan.verify:
        plan.verified.add(final)
    run.done[name] = manifest
    store.write_ref(plan.workdir, name, key)
    record = manifest.get("record") or {}
    status = "skipped" if record.get("status") == "skipped" else "cached"
    run.display.log.info(f"  {name:<12} {status:<8} {key[:12]}")
    return StepResult(name, status, key, final, True, 0.0, record)


def _runner_skip(run: _Run, name: str) -> dict[str, str] | None:
    """The record of a skip the runner decides without a worker (go_pipeline/skipping.py), or None."""
    from go_pipeline.skipping import cascade_skip, foreign_param_skip, param_skip

    rules, spec = run.plan.rules[name], run.plan.pipeline.steps[name]
    return (
        cascade_skip(rules.skip_if_skipped, spec.inputs, run.done)
        or param_skip(rules.skip_if_empty, run.plan.params[name])
        or foreign_param_skip(rules.skip_if_param, run.plan.params)
    )


def _work_dirs(plan: _Plan, name: str, key: str) -> tuple[Path, Path]:
    """A fresh temp folder for the step's outputs and its (persistent) checkpoint folder."""
    tmp = store.artifacts_root(plan.workdir, name) / f"{store.TMP_PREFIX}{key[:16]}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    ckpt = store.checkpoint_path(plan.workdir, name, key)
    ckpt.mkdir(parents=True, exist_ok=True)
    return tmp, ckpt


def _job(run: _Run, name: str, inputs: dict[str, dict[str, Any]], tmp: Path, ckpt: Path) -> dict[str, Any]:
    """What the worker needs to run the step (go_pipeline/worker.py reads it as JSON)."""
    plan, spec = run.plan, run.plan.pipeline.steps[name]
    step_inputs = {
        n: (v["path"] if v["step"] is None else str(store.artifact_path(plan.workdir, v["step"], v["key"])))
        for n, v in inputs.items()
    }
    return {
        "step": name,
        "module": spec.module,
        "callable": spec.callable,
        "inputs": step_inputs,
        "params": plan.params[name],
        "out_dir": str(tmp),
        "checkpoint_dir": str(ckpt),
        "seed": plan.seed,
        "device": run.options.device,
        "parent_pid": os.getpid(),
        "pipeline_path": str(plan.pipeline.path),
        "sys_path": _worker_sys_path(),
    }


def _launch(run: _Run, name: str, job: dict[str, Any], skip: dict[str, str] | None):
    """Run the step's worker (or, for a runner-decided skip, write its skipped outputs) into the job's
    ``out_dir``; an exception removes that folder. Returns the execution record."""
    from go_pipeline.executor import Execution, execute
    from go_pipeline.skipping import write_skipped_outputs

    spec, tmp = run.plan.pipeline.steps[name], Path(job["out_dir"])
    try:
        if skip is not None:  # nothing to do: no worker process (see go_pipeline/skipping.py)
            write_skipped_outputs(tmp, spec.outputs, skip, _module_file(spec))
            return Execution(True, 0.0, 0.0, 0.0, "cpu", dict(skip))
        keep = (run.lock_fd,) if run.lock_fd is not None else ()
        return execute(job, run.display, in_process=run.options.in_process, keep_fds=keep)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        run.display.end_step()


def _commit(run: _Run, name: str, key: str, inputs, tmp: Path, result, started: str) -> Path:
    """Check what the step wrote, write its manifest and rename ``tmp`` into place as the artifact of
    ``key``; a failed step raises (its error, or StepFailed) and leaves nothing behind."""
    plan, spec, display = run.plan, run.plan.pipeline.steps[name], run.display
    final = store.artifact_path(plan.workdir, name, key)
    try:
        if not result.ok:
            level = logging.INFO if display.debug else logging.DEBUG  # --debug: the step's traceback
            display.log.log(
                level, f"[{name}] failed: {result.error_type}: {result.error_message}\n{result.traceback}"
            )
            if result.error_kind == "go":
                raise _rebuild_go_error(result.error_type, result.error_message)
            tb_hint = "" if not result.traceback else f"; traceback in {display_log_path(display)}"
            raise StepFailed(f"step {name!r} failed: {result.error_type}: {result.error_message}{tb_hint}")
        missing = [o for o in spec.outputs if not (tmp / o).is_file()]
        if missing:
            raise StepFailed(
                f"step {name!r} did not write its declared output(s): {', '.join(missing)}",
                _module_file(spec),
            )
        manifest = _manifest(run, name, key, inputs, tmp, result, started)
        from go_core.io.atomic import atomic_write_json

        atomic_write_json(tmp / store.MANIFEST, manifest)
        _fsync_dir(tmp)
        if final.exists():  # --force over a complete artifact
            store.remove_tree(final)
        os.rename(tmp, final)
        _fsync_dir(final.parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    store.write_ref(plan.workdir, name, key)
    plan.verified.add(final)  # hashed just now
    run.done[name] = manifest
    return final


def _manifest(run: _Run, name: str, key: str, inputs, tmp: Path, result, started: str) -> dict[str, Any]:
    """The artifact's manifest (checked against data_schema/step_manifest.schema.json)."""
    from go_pipeline.manifest import build_manifest, check_manifest

    plan = run.plan
    outputs = folder_hashes(tmp)
    outputs.pop(store.MANIFEST, None)
    manifest = build_manifest(
        step=name,
        key=key,
        version=plan.rules[name].version,
        code=plan.code[name].files,
        seed=plan.seed,
        params=plan.params[name],
        inputs=inputs,
        outputs=outputs,
        output_sizes={rel: (tmp / rel).stat().st_size for rel in outputs},
        content_hash=combine_file_hashes(outputs),
        wall_s=result.wall_s,
        cpu_s=result.cpu_s,
        peak_mem_mb=result.peak_mem_mb,
        device=result.device,
        started=started,
        finished=_utc_now(),
        record=result.records,
        function=plan.pipeline.steps[name].function,
        external=_external(plan, name),
    )
    check_manifest(manifest, tmp / store.MANIFEST)
    return manifest


def _log_result(run: _Run, name: str, key: str, result, ran_worker: bool) -> None:
    from go_pipeline.skipping import short_reason

    status = "skipped" if result.records.get("status") == "skipped" else "ran"
    reason = str(result.records.get("reason") or "") if status == "skipped" else ""
    # a long reason was logged in full by the step: its first clause here ("repair model weights missing")
    extra = f" ({short_reason(reason) if len(reason) > 80 else reason})" if reason else ""
    if not ran_worker:
        run.display.log.info(f"  {name:<12} skipped  {key[:12]} {'(no worker)':>34}{extra}")
    else:
        run.display.log.info(
            f"  {name:<12} {status:<8} {key[:12]} {result.wall_s:7.1f} s  cpu {result.cpu_s:6.1f} s  "
            f"peak {result.peak_mem_mb:7.0f} MiB{extra}"
        )


def _check_artifact(artifact: Path, spec: StepSpec, full: bool) -> tuple[dict[str, Any] | None, str | None]:
    """(manifest, None) for a usable artifact; (None, problem) for a damaged one (unreadable manifest,
    a file missing or of the wrong size, with ``full`` a wrong sha256); (None, None) when there is none."""
    if not store.is_complete(artifact):
        return None, None
    try:
        manifest = store.verify_artifact(artifact, full)
    except store.DamagedArtifact as e:
        return None, e.message
    missing = [o for o in spec.outputs if o not in manifest["outputs"]]
    if missing:
        return None, f"declared output {missing[0]} is missing"
    return manifest, None


def _verify_inputs(run: _Run, spec: StepSpec) -> bool:
    """Before a step reads its upstream artifacts: check each one's files against their sha256 (once per
    run). A damaged one is recomputed (one log line); returns True when that happened."""
    plan, recomputed = run.plan, False
    for up in spec.upstream:
        artifact = store.artifact_path(plan.workdir, up, run.done[up]["key"])
        if artifact in plan.verified:
            continue
        try:
            store.verify_artifact(artifact, full=True)
        except store.DamagedArtifact as e:
            run.display.log.warning(
                f"  {up:<12} damaged  {run.done[up]['key'][:12]} ({e.message}); "
                f"recomputing before {spec.name} reads it"
            )
            plan.recomputed[up] = _run_one(run, up, True)
            recomputed = True
            continue
        plan.verified.add(artifact)
    return recomputed


def _worker_sys_path() -> list[str]:
    """This process's import path for the step worker, without the current directory (a scene folder
    there must not shadow the package) unless this very go_pipeline was imported from it."""
    cwd = os.path.realpath(os.getcwd())
    home = os.path.realpath(Path(__file__).resolve().parents[1])
    return [p for p in sys.path if p and (os.path.realpath(p) != cwd or cwd == home)]


def _rebuild_go_error(type_name: str, message: str) -> GoError:
    """The step's GoError (same class when it is one of go_core.errors) carrying its one-line message."""
    import go_core.errors as errors

    cls = getattr(errors, type_name, None)
    if not (isinstance(cls, type) and issubclass(cls, GoError)):
        cls = GoError
    try:
        return cls(message)
    except TypeError:
        return GoError(message)


def display_log_path(display) -> str:
    handler = getattr(display, "_file_handler", None)
    return getattr(handler, "baseFilename", "the run log")


def _module_file(spec: StepSpec) -> str:
    import importlib.util

    try:
        found = importlib.util.find_spec(spec.module)
        return found.origin if found and found.origin else spec.module
    except (ImportError, ValueError):
        return spec.module


def _remove_if_empty(path: Path) -> None:
    try:
        path.rmdir()
    except OSError:
        pass


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _utc_now() -> str:
    from go_pipeline.manifest import utc_now

    return utc_now()


def _new_log_path(workdir: Path) -> Path:
    """The path of this run's log (created only when something is written; the oldest logs beyond
    MAX_LOGS are deleted)."""
    logs = workdir / "logs"
    old = sorted(logs.glob("run-*.log"))
    for p in old[: max(0, len(old) - MAX_LOGS + 1)]:
        p.unlink(missing_ok=True)
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ")
    return logs / f"run-{stamp}.log"


def _record_unfinished(run: _Run, started: str, t0: float, status: str) -> None:
    """The history record of a run that stopped before its end (interrupted, a step failed), so
    ``go-pipeline runs`` lists it. Never raises: the original error matters."""
    plan = run.plan
    try:
        summary = RunSummary(
            plan.scene_dir, plan.workdir, plan.profile, plan.seed, list(run.results), run.display.log_file,
            started, _utc_now(), time.perf_counter() - t0, dict(plan.overrides), status,
        )  # fmt: skip
        from go_core.io.atomic import atomic_write_json

        stamp = started.replace(":", "").replace("-", "")
        atomic_write_json(plan.workdir / "runs" / f"run-{stamp}.json", summary.to_dict())
    except Exception:  # noqa: BLE001 - a record that cannot be written must not hide the run's error
        pass


def _write_summary(workdir: Path, summary: RunSummary) -> None:
    from go_core.io.atomic import atomic_write_json

    atomic_write_json(workdir / "runs" / "last.json", summary.to_dict())
    if summary.ran:  # the run history (`go-pipeline runs`): one file per run that did something
        stamp = summary.started.replace(":", "").replace("-", "")
        atomic_write_json(workdir / "runs" / f"run-{stamp}.json", summary.to_dict())


# ---------------------------------------------------------------------------------------------- status
def pipeline_status(
    scene_dir: str | Path,
    *,
    workdir: str | Path | None = None,
    profile: str | None = None,
    overrides: dict[str, Any] | None = None,
    seed: int = 0,
    pipeline_path: str | Path | None = None,
    allow_custom_steps: bool | None = None,
    verify: bool = False,
    allow_outside: bool = False,
) -> list[StatusRow]:
    """Every step as fresh (its artifact for the current key exists), stale (an older artifact exists;
    the reason says what changed), damaged (its artifact does not match its manifest, or the manifest is
    unreadable: the next run recomputes it) or missing (never run). Reads manifests and file stats; with
    ``verify`` also hashes every artifact file against its manifest."""
    plan = _plan(scene_dir, workdir, profile, overrides, seed, pipeline_path, None, allow_custom_steps)
    plan.allow_outside = bool(allow_outside)
    store.check_scene_binding(plan.workdir, plan.scene_dir, bind=False)
    needs_scene = any(up == SCENE_INPUT for s in plan.pipeline.steps.values() for up in s.inputs.values())
    scene_hash = _scene_hash(plan, cache_writable=plan.workdir.is_dir()) if needs_scene else None
    done: dict[str, dict[str, Any]] = {}
    rows: list[StatusRow] = []
    states: dict[str, str] = {}
    for name, spec in plan.pipeline.steps.items():
        previous_dir = store.artifact_dir(plan.workdir, name)
        previous = store.read_manifest(previous_dir) if previous_dir is not None else None
        inputs = _input_hashes(spec, scene_hash, done, plan.scene_dir)
        problem = None
        if inputs is not None:
            key = _key_for(plan, name, inputs, done)
            manifest, problem = _check_artifact(store.artifact_path(plan.workdir, name, key), spec, verify)
            if manifest is not None:
                done[name] = manifest
                rows.append(StatusRow(name, "fresh", "", key))
                states[name] = "fresh"
                continue
        else:
            key = None
        if problem is not None:
            state, reasons = "damaged", [problem]
        elif previous is None:
            state, reasons = "missing", ["never run"]
        else:
            state, reasons = "stale", _what_changed(plan, name, previous, inputs)
        blocked = [u for u in spec.upstream if states.get(u) != "fresh"]
        if blocked:
            reasons.append("upstream " + ", ".join(f"{u} is {states[u]}" for u in blocked))
        rows.append(StatusRow(name, state, "; ".join(reasons) or "key changed", key))
        states[name] = state
    if plan.workdir.is_dir():
        _hash_cache(plan).save()
    return rows


def _flat(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested params (another step's params given to this one) as dotted names: coarse.lambda_mask."""
    flat: dict[str, Any] = {}
    for k, v in params.items():
        if isinstance(v, dict):
            flat.update(_flat(v, f"{prefix}{k}."))
        else:
            flat[f"{prefix}{k}"] = v
    return flat


def _what_changed(
    plan: _Plan, name: str, previous: dict[str, Any], inputs: dict[str, dict[str, Any]] | None
) -> list[str]:
    reasons: list[str] = []
    if previous.get("version") != plan.rules[name].version:
        reasons.append(f"version changed {previous.get('version')} -> {plan.rules[name].version}")
    changed = changed_files(previous.get("code"), plan.code[name].files)
    if changed:
        more = f" (+{len(changed) - 3} more)" if len(changed) > 3 else ""
        reasons.append(f"code changed: {', '.join(changed[:3])}{more}")
    old_params, new_params = _flat(previous.get("params") or {}), _flat(plan.params[name])
    for p in sorted(set(old_params) | set(new_params)):
        if old_params.get(p, "<unset>") != new_params.get(p, "<unset>"):
            reasons.append(
                f"param {p} changed {old_params.get(p, '<unset>')!r} -> {new_params.get(p, '<unset>')!r}"
            )
    from go_pipeline.external import describe_external_changes

    reasons.extend(describe_external_changes(previous.get("external"), _external(plan, name)))
    if previous.get("seed") != plan.seed:
        reasons.append(f"seed changed {previous.get('seed')} -> {plan.seed}")
    if inputs is not None:
        old_inputs = previous.get("inputs") or {}
        for n in sorted(set(old_inputs) | set(inputs)):
            old, new = old_inputs.get(n), inputs.get(n)
            if old is None or new is None or old.get("content_hash") != new.get("content_hash"):
                what = "scene folder" if new is not None and new.get("step") is None else "input"
                reasons.append(f"{what} {n!r} changed")
    return reasons
