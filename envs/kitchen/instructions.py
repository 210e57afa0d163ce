"""FrankaKitchen's instruction format: six sub-tasks (goal id = index in ``tasks.TASK_NAMES``), each with its own
training and test sentences.

Instruction file: ``{"kitchen": {"subtasks": {"<sub-task>": {"train": [...], "test": [...]}, ...}}}`` with exactly
the six sub-tasks; sentences are goal-major (``TASK_NAMES`` order), then in the order of the file. A user's own
phrasings: ``{"kitchen": {"<sub-task>": ["sentence", ...], ...}}`` (any subset of the sub-tasks).
"""

from __future__ import annotations

from pathlib import Path

from envs.instructions import InstructionFormat, SentencesByGoal, section, string_list
from envs.kitchen.tasks import NUM_TASKS, TASK_NAMES


def read_sentences(data: dict, path: Path) -> dict[str, SentencesByGoal]:
    """``{"train": (sentences, goal ids), "test": ...}`` of an instruction file's ``kitchen`` object."""
    subtasks = section(data, "kitchen", path).get("subtasks")
    if not isinstance(subtasks, dict) or set(subtasks) != set(TASK_NAMES):
        raise ValueError(f"instruction file {path}: kitchen.subtasks must have exactly the keys {list(TASK_NAMES)}")
    out = {}
    for split in ("train", "test"):
        sentences, goals = [], []
        for goal, name in enumerate(TASK_NAMES):
            entry = subtasks[name]
            if not isinstance(entry, dict):
                raise ValueError(f"instruction file {path}: kitchen.subtasks[{name!r}] must be an object")
            listed = string_list(entry.get(split), f"kitchen.subtasks[{name!r}].{split}", path)
            sentences += listed
            goals += [goal] * len(listed)
        out[split] = (sentences, goals)
    return out


def read_user_sentences(data: dict, path: Path) -> SentencesByGoal:
    """``(sentences, goal ids)`` of a user file's ``kitchen`` object (sub-task name -> sentences)."""
    found = data.get("kitchen")
    if found is None:
        raise ValueError(f"instruction file {path} has no 'kitchen' entry (keys: {', '.join(data) or 'none'})")
    if not isinstance(found, dict) or not found:
        raise ValueError(f"instruction file {path}: 'kitchen' must map sub-task names to lists of sentences")
    sentences, goals = [], []
    for name, listed in found.items():
        if name not in TASK_NAMES:
            raise ValueError(
                f"instruction file {path}: unknown kitchen sub-task {name!r}; valid: {', '.join(TASK_NAMES)}"
            )
        listed = string_list(listed, f"kitchen[{name!r}]", path)
        sentences += listed
        goals += [TASK_NAMES.index(name)] * len(listed)
    return sentences, goals


INSTRUCTION_FORMAT = InstructionFormat(NUM_TASKS, read_sentences, read_user_sentences, aliases=("kitchen-all",))
