"""Natural-language instruction sets of the registered envs, split into train / test, with jit-ready lookups.

Each env package says how its instructions are read (an ``envs.InstructionFormat`` registered with
``envs.register_instruction_format``); this module looks the format up by env name and knows no env.

Sentence order (fixed, shared with the embedding cache): all training sentences first, then all test sentences, each
in the order of the env's format. Kitchen: goal-major (``TASK_NAMES`` order of ``envs/kitchen/tasks.py``), then the
order of the data file. CLEVR: pattern-major (pattern p, then goal id g: row ``p * 80 + g``), so keeping the first k
training patterns keeps the first ``k * 80`` rows. ``InstructionSet.sentence_ids`` always gives a sentence's row in
the full list (``split="all"``), which is also its row in ``build_cache(env)``.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from envs.instructions import (
    InstructionFormat,
    SentencesByGoal,
    instruction_envs,
    instruction_format,
    register_instruction_format,
)

INSTRUCTIONS_FILE = Path(__file__).parent / "data" / "instructions.json"
DEVELOPMENT_FILE = Path(__file__).parent / "data" / "development.json"
"""Our own development set of phrasings (new verbs, politeness, word order, synonyms), in the user-file format of
``load_user_instructions``: it measures robustness to unseen phrasings (``experiments.generalize RUN --instructions
talar_jax/language/data/development.json``) and never trains anything."""
"""Package copy of the instruction data (paper Appendix D.1)."""

SPLITS: tuple[str, ...] = ("train", "test", "all")

__all__ = [  # InstructionFormat, SentencesByGoal and register_instruction_format are envs.instructions' own
    "DEVELOPMENT_FILE",
    "INSTRUCTIONS_FILE",
    "SPLITS",
    "InstructionFormat",
    "InstructionSet",
    "SentencesByGoal",
    "canonical_env",
    "goal_lookup",
    "load_instructions",
    "load_user_instructions",
    "register_instruction_format",
]


@dataclasses.dataclass(frozen=True, eq=False)
class InstructionSet:
    """Sentences of one env and split, their goal ids and jit-ready goal -> sentence lookups.

    Attributes:
        env: canonical env name ("clevr" or "kitchen").
        split: "train", "test" or "all".
        sentences: (S,) the instructions.
        goal_ids: (S,) int32 goal id of each sentence (env goal ids).
        is_train: (S,) bool, True for training sentences.
        sentence_ids: (S,) int32 row of each sentence in the env's full list (split "all") and in its cache.
        num_goals: number of goals of the env (6 or 80).
        goal_sentences: (num_goals, max_per_goal) int32 indices into ``sentences`` of each goal's sentences,
            padded with -1.
        goal_sentence_counts: (num_goals,) int32 number of valid entries per row of ``goal_sentences``.
    """

    env: str
    split: str
    sentences: tuple[str, ...]
    goal_ids: np.ndarray
    is_train: np.ndarray
    sentence_ids: np.ndarray
    num_goals: int
    goal_sentences: np.ndarray
    goal_sentence_counts: np.ndarray

    @property
    def splits(self) -> np.ndarray:
        """(S,) bool, alias of ``is_train``."""
        return self.is_train

    def __len__(self) -> int:
        return len(self.sentences)

    def goal_cache_rows(self) -> np.ndarray:
        """(num_goals, max_per_goal) int32 like ``goal_sentences`` but holding cache rows (``sentence_ids``)."""
        return np.where(self.goal_sentences >= 0, self.sentence_ids[np.maximum(self.goal_sentences, 0)], -1).astype(
            np.int32
        )


def goal_lookup(goal_ids: np.ndarray, num_goals: int) -> tuple[np.ndarray, np.ndarray]:
    """Goal -> sentence index table.

    Args:
        goal_ids: (S,) goal id of each sentence.
        num_goals: number of goals.

    Returns:
        ``(goal_sentences, counts)``: (num_goals, max_per_goal) int32 sentence indices in order, padded with -1,
        and (num_goals,) int32 counts. Draw a sentence of goal g inside jit with
        ``goal_sentences[g, jax.random.randint(key, (), 0, counts[g])]``.
    """
    goal_ids = np.asarray(goal_ids)
    counts = np.bincount(goal_ids, minlength=num_goals).astype(np.int32)
    table = np.full((num_goals, max(int(counts.max(initial=0)), 1)), -1, np.int32)
    for goal in range(num_goals):
        rows = np.flatnonzero(goal_ids == goal)
        table[goal, : len(rows)] = rows
    return table, counts


def canonical_env(env: str) -> str:
    """Maps an env or registered variant name to the env whose instructions it uses, with one clear error."""
    instruction_format(env)  # the error naming the valid names
    return instruction_envs()[env]


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"instruction file {path} does not exist")
    text = path.read_text(encoding="utf-8")
    if not text.strip():
        raise ValueError(f"instruction file {path} is empty")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"instruction file {path} is not valid JSON: {error}") from None
    if not isinstance(data, dict):
        raise ValueError(f"instruction file {path} must hold a JSON object with keys 'kitchen' and 'clevr'")
    return data


def _check_no_leak(train: list[str], test: list[str], env: str, path: Path) -> None:
    def norm(sentence: str) -> str:
        return " ".join(sentence.lower().split())

    for name, sentences in (("train", train), ("test", test)):
        if len({norm(s) for s in sentences}) != len(sentences):
            raise ValueError(f"instruction file {path}: {env} {name} split has duplicate sentences")
    leaked = sorted({norm(s) for s in train} & {norm(s) for s in test})
    if leaked:
        raise ValueError(f"instruction file {path}: {env} test sentences also in train: {leaked[:3]}")


def load_instructions(
    env: str,
    split: str,
    num_patterns: int | None = None,
    *,
    instructions_file: str | os.PathLike | None = None,
) -> InstructionSet:
    """The instructions of an env and split.

    Args:
        env: "clevr" or "kitchen" (or the variants "clevr-arrangement", "kitchen-all").
        split: "train", "test" or "all" (train sentences first).
        num_patterns: keep only the first k training patterns (CLEVR, paper Table 3) or the first k training
            instructions of each sub-task (kitchen); test sentences are never reduced. None keeps all.
        instructions_file: another JSON file of the package file's layout (default: the package data).

    Returns:
        The ``InstructionSet``.
    """
    env = canonical_env(env)
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
    fmt = instruction_format(env)
    path = Path(instructions_file) if instructions_file is not None else fmt.default_file or INSTRUCTIONS_FILE
    by_split = fmt.read(_read_json(path), path)
    num_goals = fmt.num_goals
    (train, train_goals), (test, test_goals) = by_split["train"], by_split["test"]
    _check_no_leak(train, test, env, path)

    sentences = train + test
    goal_ids = np.array(train_goals + test_goals, np.int32)
    is_train = np.arange(len(sentences)) < len(train)
    keep = np.ones(len(sentences), bool)
    if num_patterns is not None:
        max_patterns = int(np.bincount(train_goals).max())
        if not isinstance(num_patterns, int) or not 1 <= num_patterns <= max_patterns:
            raise ValueError(f"num_patterns must be an int in [1, {max_patterns}] or None, got {num_patterns!r}")
        rank = np.zeros(len(sentences), int)  # position of a training sentence among its goal's
        for goal in range(num_goals):
            rows = np.flatnonzero(is_train & (goal_ids == goal))
            rank[rows] = np.arange(len(rows))
        keep &= ~is_train | (rank < num_patterns)
    if split != "all":
        keep &= is_train == (split == "train")
    sentence_ids = np.flatnonzero(keep).astype(np.int32)
    goal_sentences, counts = goal_lookup(goal_ids[sentence_ids], num_goals)
    return InstructionSet(
        env=env,
        split=split,
        sentences=tuple(sentences[i] for i in sentence_ids),
        goal_ids=goal_ids[sentence_ids],
        is_train=is_train[sentence_ids],
        sentence_ids=sentence_ids,
        num_goals=num_goals,
        goal_sentences=goal_sentences,
        goal_sentence_counts=counts,
    )


def load_user_instructions(path: str | os.PathLike, env: str) -> tuple[list[str], np.ndarray]:
    """A user's own phrasings of one env's goals: ``(sentences, goal ids)``.

    The file is a JSON object with ``"kitchen": {"<sub-task>": ["sentence", ...], ...}`` (any subset of the six
    sub-tasks) and/or ``"clevr_patterns": ["... {subject} ... {relation} ... {object} ...", ...]`` (each pattern
    filled for all 80 goals as the project fills its own). Other keys are ignored.

    Raises:
        ValueError: one line naming the problem (no entry for ``env``, an unknown sub-task, a pattern without its
            placeholders, an empty list or sentence).
    """
    env = canonical_env(env)
    path = Path(path)
    data = _read_json(path)
    read_user = instruction_format(env).read_user
    if read_user is None:
        raise ValueError(f"env {env!r} takes no user instruction files")
    sentences, goals = read_user(data, path)
    return sentences, np.array(goals, np.int32)
