"""A small logger interface for namespaced metrics (``eval/train/success``, ``train/sps``): terminal, JSONL, list."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Protocol

import numpy as np


def to_python(value: Any) -> Any:
    """Arrays and numpy scalars -> floats / nested lists (JSON-ready); NaN -> None."""
    if isinstance(value, dict):
        return {key: to_python(item) for key, item in value.items()}
    array = np.asarray(value)
    if array.dtype.kind in "iub":
        return array.tolist()
    if array.dtype.kind == "f":
        if array.ndim == 0:
            number = float(array)
            return None if math.isnan(number) else number
        return [to_python(item) for item in array]
    return value


class Logger(Protocol):
    """Receives ``write(step, metrics)`` after every chunk of updates; ``close()`` at the end."""

    def write(self, step: int, metrics: dict[str, Any]) -> None: ...

    def close(self) -> None: ...


class NoOpLogger:
    """Discards everything."""

    def write(self, step: int, metrics: dict[str, Any]) -> None:
        del step, metrics

    def close(self) -> None:
        pass


class ListLogger:
    """Keeps ``(step, metrics)`` records in memory (for tests)."""

    def __init__(self):
        self.records: list[tuple[int, dict[str, Any]]] = []

    def write(self, step: int, metrics: dict[str, Any]) -> None:
        self.records.append((step, to_python(metrics)))

    def close(self) -> None:
        pass


class TerminalLogger:
    """Prints the scalar metrics whose key starts with one of ``prefixes`` on one line."""

    def __init__(self, prefixes: tuple[str, ...] = ("eval/", "train/")):
        self.prefixes = prefixes

    def write(self, step: int, metrics: dict[str, Any]) -> None:
        parts = [
            f"{key}={value:.4g}"
            for key, value in to_python(metrics).items()
            if key.startswith(self.prefixes) and isinstance(value, float)
        ]
        print(f"[{step}] " + " ".join(parts), flush=True)

    def close(self) -> None:
        pass


class JsonLinesLogger:
    """Appends one JSON object ``{"step": ..., **metrics}`` per line to ``path``."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def write(self, step: int, metrics: dict[str, Any]) -> None:
        with self.path.open("a") as file:
            file.write(json.dumps({"step": step, **to_python(metrics)}) + "\n")

    def close(self) -> None:
        pass


class TensorBoardLogger:
    """Writes every numeric metric as a TensorBoard scalar under ``log_dir`` (``pip install -e .[tensorboard]``).

    A metric with one value per seed is written as its mean (``key``) and per seed (``key/seed_<i>``); follow a run
    with ``tensorboard --logdir <log_dir>`` while it trains.
    """

    def __init__(self, log_dir: str | Path):
        try:
            from tensorboardX import SummaryWriter
        except ImportError as error:
            raise ImportError("the TensorBoard writer needs tensorboardX: pip install -e .[tensorboard]") from error
        self.writer = SummaryWriter(str(log_dir))

    def write(self, step: int, metrics: dict[str, Any]) -> None:
        for key, value in to_python(metrics).items():
            values = value if isinstance(value, list) else [value]
            if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
                continue  # nested, missing (NaN) or non-numeric
            self.writer.add_scalar(key, float(np.mean(values)), step)
            if len(values) > 1:
                for seed, seed_value in enumerate(values):
                    self.writer.add_scalar(f"{key}/seed_{seed}", float(seed_value), step)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


class MultiLogger:
    """Forwards to several loggers."""

    def __init__(self, *loggers: Logger):
        self.loggers = loggers

    def write(self, step: int, metrics: dict[str, Any]) -> None:
        for logger in self.loggers:
            logger.write(step, metrics)

    def close(self) -> None:
        for logger in self.loggers:
            logger.close()
