"""The optional TensorBoard writer: scalars (mean and per seed) read back from its event file."""

import struct
from pathlib import Path

import numpy as np
import pytest

from experiments.config import ExperimentConfig, resolve
from talar_jax.logging import TensorBoardLogger

event_pb2 = pytest.importorskip("tensorboardX.proto.event_pb2")


def read_scalars(log_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(step, value)] from the TFRecord event files in ``log_dir``."""
    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(log_dir.glob("events.out.tfevents.*")):
        data, offset = path.read_bytes(), 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset : offset + 8])
            event = event_pb2.Event.FromString(data[offset + 12 : offset + 12 + length])
            offset += 12 + length + 4
            for value in event.summary.value:
                scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_tensorboard_logger_writes_means_and_seeds(tmp_path):
    logger = TensorBoardLogger(tmp_path)
    logger.write(1, {"eval/train/success": np.array([0.5, 1.0]), "train/sps": 1234.0, "note": "text", "gone": np.nan})
    logger.write(2, {"eval/train/success": np.array([0.75, 0.25]), "train/sps": 1500.0})
    logger.close()
    scalars = read_scalars(tmp_path)
    assert scalars["eval/train/success"] == [(1, 0.75), (2, 0.5)]
    assert scalars["eval/train/success/seed_1"] == [(1, 1.0), (2, 0.25)]
    assert scalars["train/sps"] == [(1, 1234.0), (2, 1500.0)]
    assert "note" not in scalars and "gone" not in scalars


def test_tensorboard_option_is_not_part_of_the_policy_key():
    from experiments.config import KEY_EXCLUDED_FIELDS

    assert "tensorboard" in KEY_EXCLUDED_FIELDS
    assert resolve(ExperimentConfig(env="clevr", tensorboard=True)).tensorboard
