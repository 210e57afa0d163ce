"""Pluggable conditioners: instruction id of an episode -> the conditioning vector the policy reads."""

from __future__ import annotations

import abc
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

SPLITS: tuple[str, ...] = ("train", "test")


def check_split(split: str) -> str:
    """Returns ``split`` or raises one error naming the valid splits."""
    if split not in SPLITS:
        raise ValueError(f"unknown instruction split {split!r}; valid splits: {', '.join(SPLITS)}")
    return split


class Conditioner(abc.ABC):
    """Chooses an instruction for a new episode of a goal and turns it into a (size,) vector.

    ``sample`` and ``apply`` are pure and jit-able; ``split`` is static. ``init`` returns the conditioner's
    parameters (``{}`` if none), which PPO passes back to ``apply`` and, when ``trainable``, optimises jointly
    with the policy; a frozen conditioner's parameters (e.g. a translated TL table) get no gradient or Adam state.
    """

    size: int
    trainable: bool = True

    def init(self, rng: jax.Array) -> Any:
        """Trainable parameters (a pytree; ``{}`` when the conditioner has none)."""
        del rng
        return {}

    @abc.abstractmethod
    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        """() int32 instruction id for a new episode of ``goal``; -1 if the goal has none in ``split``."""

    @abc.abstractmethod
    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        """(size,) float32 conditioning vector of an instruction id (zeros for -1)."""

    def apply_batch(self, params: Any, instructions: jax.Array) -> jax.Array:
        """(B, size) vectors of (B,) instruction ids: what the policy's loss reads (``apply`` on each by default; a
        conditioner with a costly shared encoder overrides it to run the encoder once per batch)."""
        return jax.vmap(self.apply, in_axes=(None, 0))(params, instructions)

    def freeze(self, params: Any) -> Any:
        """Parameters ``apply`` / ``apply_batch`` read while acting with fixed parameters (a rollout, an
        evaluation): ``params`` itself by default; a conditioner with a costly encoder precomputes every
        instruction's vector here, once per rollout instead of once per env step."""
        return params


def split_instruction_ids(goal_sentences_by_split: Mapping[str, tuple[Any, Any]], split: str) -> np.ndarray:
    """Sorted distinct instruction ids of a split's padded (lookup, counts) (``InstructionSampler``'s format)."""
    lookup, counts = (np.asarray(a) for a in goal_sentences_by_split[check_split(split)])
    return np.unique(lookup[np.arange(lookup.shape[1])[None, :] < counts[:, None]])


def gather_table_codes(params: Any, instructions: jax.Array, encode, loss_rows: jax.Array, num_instructions: int):
    """(..., size) rows of a table encoding, zeros for -1: ``params`` frozen as ``{"codes": (N, size)}`` (acting),
    or, in the loss, ``encode(params, loss_rows)`` in one pass with every other row zero."""
    if "codes" in params:
        codes = params["codes"]
    else:
        encoded = encode(params, loss_rows)
        codes = jnp.zeros((num_instructions, encoded.shape[-1]), encoded.dtype).at[loss_rows].set(encoded)
    out = codes[jnp.maximum(instructions, 0)]
    return jnp.where((instructions >= 0)[..., None], out, 0.0)


class GoalOneHotConditioner(Conditioner):
    """The oracle's conditioner: the instruction id is the goal id and the vector is its one-hot."""

    def __init__(self, num_goals: int):
        if num_goals < 1:
            raise ValueError(f"num_goals must be >= 1, got {num_goals}")
        self.num_goals = int(num_goals)
        self.size = self.num_goals

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        del rng
        check_split(split)
        return jnp.asarray(goal, jnp.int32)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        del params
        return jax.nn.one_hot(instruction, self.num_goals, dtype=jnp.float32)


class InstructionSampler:
    """Draws an instruction id of a goal uniformly from a padded per-split lookup (pure, jit-able).

    Args:
        goal_sentences_by_split: split -> (lookup (num_goals, max_per_goal) int32 instruction ids padded with
            -1, counts (num_goals,) number of valid entries per goal). A goal with count 0 samples -1.
        num_instructions: when given, every valid id must lie in [0, num_instructions).
    """

    def __init__(self, goal_sentences_by_split: Mapping[str, tuple[Any, Any]], num_instructions: int | None = None):
        self._lookups: dict[str, tuple[jax.Array, jax.Array]] = {}
        for split, (lookup, counts) in goal_sentences_by_split.items():
            check_split(split)
            lookup, counts = np.asarray(lookup, np.int32), np.asarray(counts, np.int32)
            if lookup.ndim != 2 or counts.shape != (lookup.shape[0],):
                raise ValueError(
                    f"split {split!r}: lookup must be (num_goals, max_per_goal) and counts (num_goals,), "
                    f"got {lookup.shape} and {counts.shape}"
                )
            valid = np.arange(lookup.shape[1])[None, :] < counts[:, None]
            upper = num_instructions if num_instructions is not None else np.iinfo(np.int32).max
            if np.any(lookup[valid] < 0) or np.any(lookup[valid] >= upper):
                raise ValueError(f"split {split!r}: valid instruction ids must lie in [0, {upper})")
            self._lookups[split] = (jnp.asarray(lookup), jnp.asarray(counts))

    @property
    def splits(self) -> tuple[str, ...]:
        return tuple(self._lookups)

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        check_split(split)
        if split not in self._lookups:
            raise ValueError(f"no instructions for split {split!r}; available: {', '.join(self._lookups)}")
        lookup, counts = self._lookups[split]
        count = counts[goal]
        index = jax.random.randint(rng, (), 0, jnp.maximum(count, 1))
        return jnp.where(count > 0, lookup[goal, index], -1).astype(jnp.int32)


class InstructionTableConditioner(Conditioner):
    """Instruction id -> a row of a (num_instructions, size) table; instructions drawn per goal and split.

    The table travels in the conditioner's parameters (``init`` returns ``{"table": table}``), so seeds run
    vmapped can each carry their own table (one translated TL per seed). ``apply`` reads ``params["table"]``
    (or the constructor's table when ``params`` has none). A frozen table (``trainable=False``, e.g. a translated
    task language) gets no gradient, and PPO gives it no optimiser state; a trainable one is optimised with the
    policy.

    Args:
        table: (num_instructions, size) conditioning vector of every instruction (e.g. a translated task
            language, or a sentence encoding).
        goal_sentences_by_split: split -> (lookup (num_goals, max_per_goal) int32 instruction ids padded with
            -1, counts (num_goals,) number of valid entries per goal). A goal with count 0 samples -1.
        trainable: whether PPO optimises the table.
    """

    def __init__(
        self,
        table: Any,
        goal_sentences_by_split: Mapping[str, tuple[Any, Any]],
        trainable: bool = False,
    ):
        table = np.asarray(table, np.float32)
        if table.ndim != 2:
            raise ValueError(f"table must be (num_instructions, size), got shape {table.shape}")
        self.table = jnp.asarray(table)
        self.size = int(table.shape[1])
        self.trainable = trainable
        self.sampler = InstructionSampler(goal_sentences_by_split, num_instructions=table.shape[0])

    def init(self, rng: jax.Array) -> Any:
        del rng
        return {"table": self.table}

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        return self.sampler.sample(rng, goal, split)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        table = params.get("table", self.table) if params else self.table
        if not self.trainable:
            table = jax.lax.stop_gradient(table)
        row = table[jnp.maximum(instruction, 0)]
        return jnp.where(instruction >= 0, row, 0.0)
