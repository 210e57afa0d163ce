"""Cached pipeline stages: a stage's outputs are reused when the hash of its inputs is unchanged.

Each stage writes into ``<run>/<stage>/`` and finishes by atomically writing ``<run>/<stage>/stage.json``
with the key of its inputs. A stage whose ``stage.json`` is missing (interrupted) or carries another key
(inputs changed) runs again; everything downstream has a key that includes its upstream keys.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from talar_jax.checkpoint import write_json_atomic


def to_jsonable(value: Any) -> Any:
    """Dataclasses, tuples, paths and numpy scalars -> plain JSON values (stable key order)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "item") and callable(value.item):
        return value.item()
    return value


def stable_hash(*parts: Any) -> str:
    """A short sha256 of JSON-serialised parts (configs, upstream keys)."""
    payload = json.dumps([to_jsonable(p) for p in parts], sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def finished_record(stage_dir: Path) -> dict[str, Any] | None:
    """The ``stage.json`` record of a finished stage folder (key, summary, seconds), or None."""
    marker = stage_dir / "stage.json"
    return json.loads(marker.read_text()) if marker.is_file() else None


def _remove(path: Path) -> None:
    """Removes a stage folder, or the link to another run's folder that stands in for it."""
    if path.is_symlink():
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)


@dataclasses.dataclass(frozen=True)
class StageResult:
    """What a finished stage recorded: its folder, input key, summary and wall-clock seconds."""

    path: Path
    key: str
    summary: dict[str, Any]
    seconds: float
    reused: bool

    @classmethod
    def reused_from(cls, stage_dir: Path, record: dict[str, Any]) -> StageResult:
        """A finished stage taken as it is, from its ``stage.json`` record."""
        return cls(stage_dir, record["key"], record.get("summary", {}), record.get("seconds", 0.0), True)


def run_stage(
    run_dir: str | Path,
    name: str,
    key: str,
    body: Callable[[Path], dict[str, Any]],
    log: Callable[[str], None] = print,
    reuse_from: Sequence[str | Path] = (),
) -> StageResult:
    """Runs ``body(stage_dir) -> summary`` unless ``stage_dir/stage.json`` already holds ``key``.

    A stage that changes key is cleared first, except for ``checkpoints/`` of the *same* key, which the body
    may resume from (long stages checkpoint into ``stage_dir/checkpoints``). ``reuse_from``: other run folders;
    where one holds this stage finished with the same key (``<folder>/<name>/stage.json``), it is copied here
    instead of run (the key hashes every input, so the outputs would be the same).
    """
    stage_dir = Path(run_dir) / name
    marker = stage_dir / "stage.json"
    record = finished_record(stage_dir)
    if record is not None and record.get("key") == key:
        log(f"[{name}] up to date (key {key}), reusing {stage_dir}")
        return StageResult.reused_from(stage_dir, record)
    for source in reuse_from:
        found = Path(source) / name
        found_record = finished_record(found)
        if found_record is None or found_record.get("key") != key or found.resolve() == stage_dir.resolve():
            continue
        partial = stage_dir.with_name(stage_dir.name + ".copying")  # renamed when whole: no half copy looks finished
        _remove(partial)
        shutil.copytree(found, partial)
        _remove(stage_dir)
        partial.rename(stage_dir)
        log(f"[{name}] finished with the same key (key {key}) in {found}: copied, not run")
        return StageResult.reused_from(stage_dir, found_record)
    if record is not None:
        log(f"[{name}] inputs changed ({record.get('key')} -> {key}): running again")
        _remove(stage_dir)
    pending = stage_dir / "pending.json"
    if pending.exists() and json.loads(pending.read_text()).get("key") != key:
        shutil.rmtree(stage_dir)
    stage_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(pending, {"key": key})
    log(f"[{name}] running (key {key})")
    start = time.perf_counter()
    summary = body(stage_dir)
    seconds = time.perf_counter() - start
    write_json_atomic(marker, to_jsonable({"key": key, "summary": summary, "seconds": seconds}))
    pending.unlink(missing_ok=True)
    log(f"[{name}] done in {seconds:.1f} s")
    return StageResult(stage_dir, key, summary, seconds, False)
