"""Orbax checkpoints of the training state after each chunk, with the resolved config as JSON beside them."""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import jax
import orbax.checkpoint as ocp
from flax import serialization

_Record = TypeVar("_Record")


def config_to_dict(config: Any) -> dict[str, Any]:
    """A frozen dataclass config -> a JSON-ready dict (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def save_tree(path: str | Path, tree: Any) -> None:
    """Writes a pytree of arrays with msgpack (atomic rename): a stage's trained parameters."""
    path = Path(path)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(serialization.msgpack_serialize(jax.device_get(tree)))
    tmp.replace(path)


def load_tree(path: str | Path) -> Any:
    """Reads a pytree written by ``save_tree``."""
    return serialization.msgpack_restore(Path(path).read_bytes())


def write_json_atomic(path: str | Path, payload: Any) -> None:
    """Writes JSON to a temporary file beside ``path`` and renames it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(handle, "w") as file:
        json.dump(payload, file, indent=2, sort_keys=True)
    os.chmod(temporary, 0o644)
    os.replace(temporary, path)


def read_json_record(path: Path, parse: Callable[[Any], _Record], error: type[Exception]) -> _Record:
    """``parse`` of the JSON in ``path``: ``error`` (naming the file) for text that is not JSON or for a record
    that ``parse`` rejects with ``error``; ``FileNotFoundError`` where there is no file."""
    text = path.read_text()
    try:
        data = json.loads(text)
    except json.JSONDecodeError as problem:
        raise error(f"{path} is not valid JSON ({problem})") from None
    try:
        return parse(data)
    except error as problem:
        raise error(f"{path}: {problem}") from None


def check_record_keys(
    data: Any, record: type, required: set[str] | frozenset[str], error: type[Exception], what: str
) -> None:
    """``error`` unless ``data`` is a JSON object with only the fields of the dataclass ``record`` and all of
    ``required``; ``what`` names the record (\"calibration\", \"encoding record\")."""
    if not isinstance(data, Mapping):
        article = "an" if what[:1] in "aeiou" else "a"
        raise error(f"{article} {what} must be a JSON object, got {type(data).__name__}")
    unknown = set(data) - {field.name for field in dataclasses.fields(record)}
    missing = set(required) - set(data)
    if unknown or missing:
        problems = [f"unknown keys {', '.join(sorted(unknown))}"] if unknown else []
        problems += [f"missing keys {', '.join(sorted(missing))}"] if missing else []
        raise error(f"malformed {what}: {'; '.join(problems)}")


class Checkpointer:
    """Saves/restores a training-state pytree per step under ``directory/checkpoints``.

    ``directory/config.json`` holds the config; resuming with a different config raises, naming the
    differing fields. Saving is synchronous (a killed run never leaves a half-written latest step).
    """

    def __init__(self, directory: str | Path, config: Any, max_to_keep: int = 2):
        self.directory = Path(directory).absolute()
        self.directory.mkdir(parents=True, exist_ok=True)
        config_path = self.directory / "config.json"
        resolved = config_to_dict(config)
        if config_path.exists():
            saved = json.loads(config_path.read_text())
            if saved != resolved:
                differing = sorted(k for k in set(saved) | set(resolved) if saved.get(k) != resolved.get(k))
                raise ValueError(
                    f"{self.directory} holds a run with a different config (fields {', '.join(differing)}); "
                    "use another output directory or the same config to resume"
                )
        else:
            write_json_atomic(config_path, resolved)
        options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, enable_async_checkpointing=False)
        self.manager = ocp.CheckpointManager(self.directory / "checkpoints", options=options)

    def latest_step(self) -> int | None:
        return self.manager.latest_step()

    def save(self, step: int, state: Any) -> None:
        self.manager.save(step, args=ocp.args.StandardSave(state))
        self.manager.wait_until_finished()

    def restore(self, step: int, target: Any) -> Any:
        """Restores ``step`` into the structure (and shapes/dtypes) of ``target``."""
        return self.manager.restore(step, args=ocp.args.StandardRestore(target))

    def close(self) -> None:
        self.manager.close()
