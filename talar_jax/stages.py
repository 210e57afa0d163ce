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
from collections.abc import Callable
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


@dataclasses.dataclass(frozen=True)
class StageResult:
    """What a finished stage recorded: its folder, input key, summary and wall-clock seconds."""

    path: Path
    key: str
    summary: dict[str, Any]
    seconds: float
    reused: bool


def run_stage(
    run_dir: str | Path,
    name: str,
    key: str,
    body: Callable[[Path], dict[str, Any]],
    log: Callable[[str], None] = print,
) -> StageResult:
    """Runs ``body(stage_dir) -> summary`` unless ``stage_dir/stage.json`` already holds ``key``.

    A stage that changes key is cleared first, except for ``checkpoints/`` of the *same* key, which the body
    may resume from (long stages checkpoint into ``stage_dir/checkpoints``).
    """
    stage_dir = Path(run_dir) / name
    marker = stage_dir / "stage.json"
    if marker.exists():
        record = json.loads(marker.read_text())
        if record.get("key") == key:
            log(f"[{name}] up to date (key {key}), reusing {stage_dir}")
            return StageResult(stage_dir, key, record.get("summary", {}), record.get("seconds", 0.0), True)
        log(f"[{name}] inputs changed ({record.get('key')} -> {key}): running again")
        shutil.rmtree(stage_dir)
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
