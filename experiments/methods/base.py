"""What a method is: how it turns instructions into the policy's conditioning vector, as one registered object.

A ``Method`` names itself, keys its own stages, sets up its conditioner (running those stages) and says how a
trained agent reads a sentence back (its encoding artifact, ``talar_jax.encodings``). The pipeline, the comparison
and the agent know methods only through this registry, so a new method is one module that calls
``register_method``.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from experiments.config import ExperimentConfig
from talar_jax.conditioning import Conditioner
from talar_jax.dataset import TaskDataset
from talar_jax.encodings import EncodingArtifact
from talar_jax.language import TOKEN_READOUT, EmbeddingCache, load_encoder, load_instructions, readout_features
from talar_jax.sharding import shard_seeds
from talar_jax.stages import StageResult
from talar_jax.talar import TaskLanguageData

FIT_CHECKPOINT = "checkpoints/fit.msgpack"
"""Where a supervised stage's fit saves its state after every piece (resumed while the stage's key holds)."""


@dataclasses.dataclass(frozen=True)
class MethodSetup:
    """What the IFP stage needs from a method."""

    conditioner: Conditioner
    initial_params: dict[str, Any] | None
    key: str
    encodings: np.ndarray | None  # (seeds, S, size) instruction encodings (t-SNE), None when trained by RL
    stages: dict[str, StageResult] = dataclasses.field(default_factory=dict)  # the method's own stages, by name

    @property
    def summary(self) -> dict[str, Any]:
        """The summaries of the method's stages, merged in order."""
        return {k: v for stage in self.stages.values() for k, v in stage.summary.items()}


def translator_readout(config: ExperimentConfig) -> str:
    """What the run's translators read of a sentence: the token states with ``talar.translator_tokens``, else the
    experiment's ``sentence_readout`` (which the NL-encoding baselines always read)."""
    return TOKEN_READOUT if config.talar.translator_tokens else config.sentence_readout


def stage_seed_keys(seed: int, stage: str, seeds: int) -> jax.Array:
    """(seeds,) keys of a stage of the run with base seed ``seed``, stable across processes (crc32 of the stage's
    name, not Python's hash): what a script retraining a stage's fit needs to match the run."""
    key = jax.random.fold_in(jax.random.PRNGKey(seed), zlib.crc32(stage.encode()))
    return jax.random.split(key, seeds)


@dataclasses.dataclass(frozen=True)
class MethodContext:
    """Inputs shared by every method of one experiment."""

    config: ExperimentConfig  # resolved
    upstream_key: str  # key of the oracle/dataset stage
    data: TaskLanguageData
    cache: EmbeddingCache
    dataset: TaskDataset
    env: Any

    @property
    def seeds(self) -> int:
        return self.config.seeds

    def stage_keys(self) -> dict[str, str]:
        """Stage folder -> key of every stage of the config's method."""
        return get_method(self.config.method).stage_keys(self.config, self.upstream_key, self.cache.key)

    def named(self, *stages: StageResult) -> dict[str, StageResult]:
        """Stages by their folder relative to ``out`` (the keys of ``stage_seconds``)."""
        return {stage.path.relative_to(self.config.out).as_posix(): stage for stage in stages}

    def seed_keys(self, stage: str) -> jax.Array:
        """(seeds,) keys of a stage (``stage_seed_keys``), sharded over the devices."""
        return shard_seeds(stage_seed_keys(self.config.seed, stage, self.seeds), self.seeds)

    def translator_data(self) -> TaskLanguageData:
        """``data`` with the translator's readout of every cached sentence (``translator_readout``): the same
        arrays unless the translator reads token states."""
        readout = translator_readout(self.config)
        if readout == self.config.sentence_readout:
            return self.data
        encoder = load_encoder(self.config.encoder)
        features = readout_features(self.cache, readout, encoder, progress=self.config.progress)
        return self.data._replace(sentence_embeddings=jnp.asarray(features, jnp.float32))

    def lookups(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """split -> (goal -> cache rows of its instructions, counts); training may keep only k sentence patterns."""
        lookups = {}
        for split in ("train", "test"):
            patterns = self.config.num_patterns if split == "train" else None
            instructions = load_instructions(self.config.env, split, num_patterns=patterns)
            lookups[split] = (instructions.goal_cache_rows(), instructions.goal_sentence_counts)
        return lookups


@dataclasses.dataclass(frozen=True)
class Method:
    """One way of conditioning the policy on an instruction.

    Attributes:
        name: the ``--method`` value and the run's folder name.
        label: the name figures and tables show.
        stage_keys: (resolved config, oracle stage key, language-cache key) -> stage folder -> key of each stage the
            method runs before the policy (the hash of exactly what the stage reads; the last is what the policy
            stage builds on).
        setup: runs (or reuses) those stages and returns the policy's conditioner (``MethodSetup``).
        encoding: (resolved config, number of goals) -> how a trained agent reads a sentence back
            (``talar_jax.encodings.EncodingArtifact``, written beside the run's ``config.json``).
    """

    name: str
    label: str
    stage_keys: Callable[[ExperimentConfig, str, str], dict[str, str]]
    setup: Callable[[MethodContext], MethodSetup]
    encoding: Callable[[ExperimentConfig, int], EncodingArtifact]


_METHODS: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """Adds (or replaces) a method; returns it."""
    _METHODS[method.name] = method
    return method


def method_names() -> tuple[str, ...]:
    """Every registered method, in the order they were registered."""
    return tuple(_METHODS)


def get_method(name: str) -> Method:
    """The method registered as ``name``, or one clear error naming the valid ones."""
    if name not in _METHODS:
        raise ValueError(f"unknown method {name!r}; valid methods: {', '.join(_METHODS)}")
    return _METHODS[name]


def method_label(name: str) -> str:
    """The label figures show for a method (its name when it is not registered)."""
    return _METHODS[name].label if name in _METHODS else name
