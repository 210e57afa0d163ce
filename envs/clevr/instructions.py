"""CLEVR-Robot's instruction format: sentence patterns with ``{subject}``, ``{relation}`` and ``{object}``
placeholders, each filled for all 80 goals (``tasks.COLORS``, the phrase of ``tasks.RELATIONS``).

Instruction file: ``{"clevr": {"train_patterns": [...], "test_patterns": [...]}}``; sentences are pattern-major
(pattern p, then goal id g: row ``p * 80 + g``). A user's own phrasings: ``{"clevr_patterns": [...]}``.
"""

from __future__ import annotations

import string
from pathlib import Path

from envs.clevr.tasks import COLORS, GOAL_DESTINATION, GOAL_RELATION, GOAL_SOURCE, NUM_GOALS, RELATIONS
from envs.instructions import InstructionFormat, SentencesByGoal, section, string_list

PATTERN_FIELDS = frozenset({"subject", "relation", "object"})


def check_pattern(pattern: str, path: Path) -> None:
    """Raises one ValueError unless ``pattern`` uses exactly the placeholders of ``PATTERN_FIELDS``."""
    try:
        fields = {name for _, name, _, _ in string.Formatter().parse(pattern) if name is not None}
    except ValueError as error:
        raise ValueError(f"instruction file {path}: clevr pattern {pattern!r} is malformed ({error})") from None
    if fields != PATTERN_FIELDS:
        raise ValueError(
            f"instruction file {path}: clevr pattern {pattern!r} must use exactly the placeholders "
            "{subject}, {relation}, {object}"
        )


def expand_patterns(patterns: list[str]) -> SentencesByGoal:
    """Every pattern filled for every goal, pattern-major: ``(sentences, goal ids)``."""
    sentences, goals = [], []
    for pattern in patterns:
        for goal in range(NUM_GOALS):
            sentences.append(
                pattern.format(
                    subject=COLORS[GOAL_SOURCE[goal]],
                    relation=RELATIONS[GOAL_RELATION[goal]][1],
                    object=COLORS[GOAL_DESTINATION[goal]],
                )
            )
            goals.append(goal)
    return sentences, goals


def read_sentences(data: dict, path: Path) -> dict[str, SentencesByGoal]:
    """``{"train": (sentences, goal ids), "test": ...}`` of an instruction file's ``clevr`` object."""
    found = section(data, "clevr", path)
    patterns = {}
    for split in ("train", "test"):
        listed = string_list(found.get(f"{split}_patterns"), f"clevr.{split}_patterns", path)
        for pattern in listed:
            check_pattern(pattern, path)
        patterns[split] = listed
    return {split: expand_patterns(listed) for split, listed in patterns.items()}


def read_user_sentences(data: dict, path: Path) -> SentencesByGoal:
    """``(sentences, goal ids)`` of a user file's ``clevr_patterns``, each filled for all 80 goals."""
    patterns = data.get("clevr_patterns")
    if patterns is None:
        raise ValueError(f"instruction file {path} has no 'clevr_patterns' entry (keys: {', '.join(data) or 'none'})")
    patterns = string_list(patterns, "clevr_patterns", path)
    for pattern in patterns:
        check_pattern(pattern, path)
    return expand_patterns(patterns)


INSTRUCTION_FORMAT = InstructionFormat(NUM_GOALS, read_sentences, read_user_sentences, aliases=("clevr-arrangement",))
