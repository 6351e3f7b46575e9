"""The artifact store: the layout of a work dir (``SCENE/.go/`` by default) and reading it back.

```
<workdir>/artifacts/<step>/<key>/       outputs + manifest.json (written last: its presence = complete)
<workdir>/artifacts/<step>/.tmp-*/      a step being written (deleted by the next run if left by a crash)
<workdir>/checkpoints/<step>/<key>/     persistent mid-step checkpoints (ctx.checkpoint_dir)
<workdir>/refs/<step>                   the key of the step's artifact used by the latest run
<workdir>/logs/run-<timestamp>.log      one log per run
<workdir>/runs/last.json                the latest run's summary
<workdir>/cache/file_hashes.json        per-file hash cache of the scene folder
<workdir>/lock                          flock'ed by a running `go-pipeline run`
<workdir>/scene                         the scene folder a --workdir outside it is bound to
```
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from go_core.errors import GoError

WORKDIR_NAME = ".go"
MANIFEST = "manifest.json"
TMP_PREFIX = ".tmp-"
TRASH_PREFIX = ".trash-"


def workdir_for(scene_dir: str | Path, workdir: str | Path | None = None) -> Path:
    """The work dir of a scene: ``workdir`` when given, else ``SCENE/.go``."""
    return Path(workdir).resolve() if workdir is not None else Path(scene_dir).resolve() / WORKDIR_NAME


SCENE_BINDING = "scene"


def check_scene_binding(workdir: Path, scene_dir: Path, bind: bool) -> None:
    """A work dir holds one scene's artifacts. ``SCENE/.go`` is bound by where it lives; any other work
    dir records its scene's path on first use (``bind``), and a different scene is then an error (its
    report would mix the two scenes' results)."""
    workdir, scene_dir = Path(workdir).resolve(), Path(scene_dir).resolve()
    if workdir == scene_dir / WORKDIR_NAME:
        return
    record = workdir / SCENE_BINDING
    try:
        bound = record.read_text(encoding="utf-8").strip()
    except OSError:
        bound = ""
    if bound and bound != str(scene_dir):
        raise GoError(
            f"this work dir holds the artifacts of another scene ({bound}); use another --workdir for "
            f"{scene_dir}, or remove this one",
            workdir,
        )
    if bind and not bound:
        from go_core.io.atomic import atomic_write_text

        atomic_write_text(record, str(scene_dir) + "\n")


def artifacts_root(workdir: Path, step: str) -> Path:
    return Path(workdir) / "artifacts" / step


def artifact_path(workdir: Path, step: str, key: str) -> Path:
    return artifacts_root(workdir, step) / key


def checkpoint_path(workdir: Path, step: str, key: str) -> Path:
    return Path(workdir) / "checkpoints" / step / key


def ref_path(workdir: Path, step: str) -> Path:
    return Path(workdir) / "refs" / step


def is_complete(artifact: Path) -> bool:
    return (artifact / MANIFEST).is_file()


class DamagedArtifact(GoError):
    """An artifact whose manifest cannot be read or whose files do not match it (``message``: the problem,
    ``path``: the artifact folder)."""


def load_manifest(artifact: str | Path) -> dict[str, Any]:
    """The manifest.json of an artifact folder; ``DamagedArtifact`` if it is unreadable or not a manifest."""
    path = Path(artifact) / MANIFEST
    try:
        with open(path, encoding="utf-8") as f:
            manifest = json.load(f)
    except (OSError, ValueError) as e:  # ValueError: JSONDecodeError and UnicodeDecodeError
        problem = f"{MANIFEST} unreadable ({type(e).__name__}: {_first(e)})"
        raise DamagedArtifact(problem, artifact) from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("outputs"), dict):
        raise DamagedArtifact(f"{MANIFEST} is not a step manifest", artifact)
    return manifest


def read_manifest(artifact: str | Path) -> dict[str, Any] | None:
    """``load_manifest``, or None for a damaged one (readers that only list artifacts)."""
    try:
        return load_manifest(artifact)
    except DamagedArtifact:
        return None


def verify_artifact(artifact: str | Path, full: bool = False) -> dict[str, Any]:
    """The artifact's manifest after checking its files against it: every listed file present with its
    recorded size (cheap: stat only), and with ``full`` also its sha256. ``DamagedArtifact`` names the
    first problem. Manifests written before sizes were recorded get the existence check only."""
    from go_pipeline.hashing import sha256_file

    artifact = Path(artifact)
    manifest = load_manifest(artifact)
    sizes = manifest.get("output_sizes") or {}
    for rel, digest in sorted(manifest["outputs"].items()):
        path = artifact / rel
        try:
            size = path.stat().st_size
        except OSError:
            raise DamagedArtifact(f"{rel} is missing", artifact) from None
        if rel in sizes and size != sizes[rel]:
            raise DamagedArtifact(f"{rel} has {size} bytes, the manifest says {sizes[rel]}", artifact)
        if full and sha256_file(path) != digest:
            problem = f"{rel} does not match its content hash (sha256 {digest[:12]}...)"
            raise DamagedArtifact(problem, artifact)
    return manifest


def _first(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:120] if text else ""


def read_ref(workdir: Path, step: str) -> str | None:
    try:
        key = ref_path(workdir, step).read_text(encoding="ascii").strip()
    except OSError:
        return None
    return key or None


def write_ref(workdir: Path, step: str, key: str) -> None:
    from go_core.io.atomic import atomic_write_text

    if read_ref(workdir, step) != key:
        atomic_write_text(ref_path(workdir, step), key + "\n")


def complete_artifacts(workdir: Path, step: str) -> list[Path]:
    """Every complete artifact of ``step``, newest (by manifest mtime) first."""
    root = artifacts_root(workdir, step)
    if not root.is_dir():
        return []
    found = [p for p in root.iterdir() if not p.name.startswith(".") and is_complete(p) and read_manifest(p)]
    return sorted(found, key=lambda p: (p / MANIFEST).stat().st_mtime_ns, reverse=True)


def artifact_dir(workdir: str | Path, step: str) -> Path | None:
    """The current artifact folder of ``step``: the one the latest run used (refs/), else the newest
    complete one; None if the step never completed."""
    workdir = Path(workdir)
    key = read_ref(workdir, step)
    if key is not None:
        p = artifact_path(workdir, step, key)
        if is_complete(p) and read_manifest(p) is not None:
            return p
    found = complete_artifacts(workdir, step)
    return found[0] if found else None


def current_manifests(workdir: str | Path) -> dict[str, dict[str, Any]]:
    """step -> manifest of its current artifact, for every step that has one."""
    workdir = Path(workdir)
    result: dict[str, dict[str, Any]] = {}
    root = workdir / "artifacts"
    if not root.is_dir():
        return result
    for step_dir in sorted(root.iterdir()):
        found = artifact_dir(workdir, step_dir.name)
        manifest = read_manifest(found) if found is not None else None
        if manifest is not None:
            result[step_dir.name] = manifest
    return result


def remove_tree(path: Path) -> None:
    """Remove a folder by first renaming it aside (so a crash mid-delete never leaves a folder that looks
    complete), then deleting it."""
    if not path.exists():
        return
    aside = path.with_name(f"{TRASH_PREFIX}{path.name}-{os.getpid()}")
    os.rename(path, aside)
    shutil.rmtree(aside, ignore_errors=True)


def sweep_leftovers(workdir: Path) -> int:
    """Delete temp and trash folders left by killed runs (call only while holding the lock)."""
    removed = 0
    for sub in ("artifacts", "checkpoints"):
        root = Path(workdir) / sub
        if not root.is_dir():
            continue
        for step_dir in root.iterdir():
            if step_dir.name.startswith(TRASH_PREFIX):
                shutil.rmtree(step_dir, ignore_errors=True)
                continue
            if not step_dir.is_dir():
                continue
            for p in step_dir.iterdir():
                if p.name.startswith((TMP_PREFIX, TRASH_PREFIX)):
                    shutil.rmtree(p, ignore_errors=True)
                    removed += 1
    return removed
