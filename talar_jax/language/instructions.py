"""Natural-language instruction sets of FrankaKitchen and CLEVR-Robot, split into train / test, with jit-ready lookups.

Sentence order (fixed, shared with the embedding cache): all training sentences first, then all test sentences.
Kitchen: goal-major (``envs.kitchen.tasks.TASK_NAMES`` order), then the order of the data file. CLEVR: pattern-major
(pattern p, then goal id g: row ``p * 80 + g``), so keeping the first k training patterns keeps the first ``k * 80``
rows. ``InstructionSet.sentence_ids`` always gives a sentence's row in the full list (``split="all"``), which is also
its row in ``build_cache(env)``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import string
from collections.abc import Callable
from pathlib import Path

import numpy as np

from envs.clevr import tasks as clevr_tasks
from envs.kitchen import tasks as kitchen_tasks

INSTRUCTIONS_FILE = Path(__file__).parent / "data" / "instructions.json"
DEVELOPMENT_FILE = Path(__file__).parent / "data" / "development.json"
"""Our own development set of phrasings (new verbs, politeness, word order, synonyms), in the user-file format of
``load_user_instructions``: it measures robustness to unseen phrasings (``experiments.generalize RUN --instructions
talar_jax/language/data/development.json``) and never trains anything."""
"""Package copy of the instruction data (paper Appendix D.1)."""

SPLITS: tuple[str, ...] = ("train", "test", "all")
_CLEVR_FIELDS = {"subject", "relation", "object"}

SentencesByGoal = tuple[list[str], list[int]]


@dataclasses.dataclass(frozen=True)
class InstructionFormat:
    """How one env's instructions are read: what a new env registers (``register_instruction_format``).

    Attributes:
        num_goals: the env's number of goal ids.
        read: ``(json data, path) -> {"train": (sentences, goal ids), "test": ...}`` from the instruction file.
        read_user: ``(json data, path) -> (sentences, goal ids)`` of a user's own phrasings
            (``load_user_instructions``), or None when the env takes none.
        aliases: other env names (variants) that share these instructions.
        default_file: the instruction file of this env (None: the package's ``INSTRUCTIONS_FILE``).
    """

    num_goals: int
    read: Callable[[dict, Path], dict[str, SentencesByGoal]]
    read_user: Callable[[dict, Path], SentencesByGoal] | None = None
    aliases: tuple[str, ...] = ()
    default_file: Path | None = None


_FORMATS: dict[str, InstructionFormat] = {}


def register_instruction_format(env: str, instruction_format: InstructionFormat) -> None:
    """Makes ``load_instructions(env, ...)`` (and the language cache) read ``env``'s instructions this way."""
    _FORMATS[env] = instruction_format


def _aliases() -> dict[str, str]:
    names = {env: env for env in _FORMATS}
    names.update({alias: env for env, fmt in _FORMATS.items() for alias in fmt.aliases})
    return names


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
    aliases = _aliases()
    if env not in aliases:
        raise ValueError(f"unknown env {env!r} for instructions; valid: {', '.join(sorted(aliases))}")
    return aliases[env]


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


def _string_list(value: object, where: str, path: Path) -> list[str]:
    if not isinstance(value, list) or not value or not all(isinstance(s, str) and s.strip() for s in value):
        raise ValueError(f"instruction file {path}: {where} must be a non-empty list of non-empty strings")
    return [s.strip() for s in value]


def _section(data: dict, env: str, path: Path) -> dict:
    section = data.get(env)
    if not isinstance(section, dict):
        raise ValueError(f"instruction file {path} has no {env!r} object")
    return section


def _kitchen_sentences(data: dict, path: Path) -> dict[str, tuple[list[str], list[int]]]:
    subtasks = _section(data, "kitchen", path).get("subtasks")
    if not isinstance(subtasks, dict) or set(subtasks) != set(kitchen_tasks.TASK_NAMES):
        raise ValueError(
            f"instruction file {path}: kitchen.subtasks must have exactly the keys {list(kitchen_tasks.TASK_NAMES)}"
        )
    out = {}
    for split in ("train", "test"):
        sentences, goals = [], []
        for goal, name in enumerate(kitchen_tasks.TASK_NAMES):
            entry = subtasks[name]
            if not isinstance(entry, dict):
                raise ValueError(f"instruction file {path}: kitchen.subtasks[{name!r}] must be an object")
            listed = _string_list(entry.get(split), f"kitchen.subtasks[{name!r}].{split}", path)
            sentences += listed
            goals += [goal] * len(listed)
        out[split] = (sentences, goals)
    return out


def _clevr_patterns(data: dict, path: Path) -> dict[str, list[str]]:
    section = _section(data, "clevr", path)
    patterns = {}
    for split in ("train", "test"):
        listed = _string_list(section.get(f"{split}_patterns"), f"clevr.{split}_patterns", path)
        for pattern in listed:
            _check_clevr_pattern(pattern, path)
        patterns[split] = listed
    return patterns


def _clevr_sentences(patterns: list[str]) -> tuple[list[str], list[int]]:
    sentences, goals = [], []
    for pattern in patterns:
        for goal in range(clevr_tasks.NUM_GOALS):
            sentences.append(
                pattern.format(
                    subject=clevr_tasks.COLORS[clevr_tasks.GOAL_SOURCE[goal]],
                    relation=clevr_tasks.RELATIONS[clevr_tasks.GOAL_RELATION[goal]][1],
                    object=clevr_tasks.COLORS[clevr_tasks.GOAL_DESTINATION[goal]],
                )
            )
            goals.append(goal)
    return sentences, goals


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
    fmt = _FORMATS[env]
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
    read_user = _FORMATS[env].read_user
    if read_user is None:
        raise ValueError(f"env {env!r} takes no user instruction files")
    sentences, goals = read_user(data, path)
    return sentences, np.array(goals, np.int32)


def _kitchen_user_sentences(data: dict, path: Path) -> SentencesByGoal:
    section = data.get("kitchen")
    if section is None:
        raise ValueError(f"instruction file {path} has no 'kitchen' entry (keys: {', '.join(data) or 'none'})")
    if not isinstance(section, dict) or not section:
        raise ValueError(f"instruction file {path}: 'kitchen' must map sub-task names to lists of sentences")
    sentences, goals = [], []
    for name, listed in section.items():
        if name not in kitchen_tasks.TASK_NAMES:
            raise ValueError(
                f"instruction file {path}: unknown kitchen sub-task {name!r}; valid: "
                f"{', '.join(kitchen_tasks.TASK_NAMES)}"
            )
        listed = _string_list(listed, f"kitchen[{name!r}]", path)
        sentences += listed
        goals += [kitchen_tasks.TASK_NAMES.index(name)] * len(listed)
    return sentences, goals


def _check_clevr_pattern(pattern: str, path: Path) -> None:
    try:
        fields = {name for _, name, _, _ in string.Formatter().parse(pattern) if name is not None}
    except ValueError as error:
        raise ValueError(f"instruction file {path}: clevr pattern {pattern!r} is malformed ({error})") from None
    if fields != _CLEVR_FIELDS:
        raise ValueError(
            f"instruction file {path}: clevr pattern {pattern!r} must use exactly the placeholders "
            "{subject}, {relation}, {object}"
        )


def _clevr_user_sentences(data: dict, path: Path) -> SentencesByGoal:
    patterns = data.get("clevr_patterns")
    if patterns is None:
        raise ValueError(f"instruction file {path} has no 'clevr_patterns' entry (keys: {', '.join(data) or 'none'})")
    patterns = _string_list(patterns, "clevr_patterns", path)
    for pattern in patterns:
        _check_clevr_pattern(pattern, path)
    return _clevr_sentences(patterns)


def _clevr_split_sentences(data: dict, path: Path) -> dict[str, SentencesByGoal]:
    return {name: _clevr_sentences(listed) for name, listed in _clevr_patterns(data, path).items()}


register_instruction_format(
    "kitchen",
    InstructionFormat(kitchen_tasks.NUM_TASKS, _kitchen_sentences, _kitchen_user_sentences, aliases=("kitchen-all",)),
)
register_instruction_format(
    "clevr",
    InstructionFormat(
        clevr_tasks.NUM_GOALS, _clevr_split_sentences, _clevr_user_sentences, aliases=("clevr-arrangement",)
    ),
)
