"""How an env's natural-language instructions are read, described by the env package itself.

An env package builds one ``InstructionFormat`` (its goal count and how its section of an instruction JSON file
becomes sentences and goal ids) and registers it with ``envs.register_instruction_format`` beside its
``register_environment`` calls. The language layer (``talar_jax.language.load_instructions``) looks it up by env name
and knows no env. Plain data and functions: nothing here imports an instruction-following library.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

SentencesByGoal = tuple[list[str], list[int]]
"""``(sentences, goal id of each sentence)``."""


@dataclasses.dataclass(frozen=True)
class InstructionFormat:
    """How one env's instructions are read: what a new env registers (``register_instruction_format``).

    Attributes:
        num_goals: the env's number of goal ids.
        read: ``(json data, path) -> {"train": (sentences, goal ids), "test": ...}`` from the instruction file.
        read_user: ``(json data, path) -> (sentences, goal ids)`` of a user's own phrasings
            (``load_user_instructions``), or None when the env takes none.
        aliases: other env names (variants) that share these instructions.
        default_file: the instruction file of this env (None: the language layer's own instruction file,
            ``talar_jax.language.instructions.INSTRUCTIONS_FILE``).
    """

    num_goals: int
    read: Callable[[dict, Path], dict[str, SentencesByGoal]]
    read_user: Callable[[dict, Path], SentencesByGoal] | None = None
    aliases: tuple[str, ...] = ()
    default_file: Path | None = None


def string_list(value: object, where: str, path: Path) -> list[str]:
    """``value`` as a non-empty list of stripped, non-empty strings, or one ValueError naming ``where`` in ``path``."""
    if not isinstance(value, list) or not value or not all(isinstance(s, str) and s.strip() for s in value):
        raise ValueError(f"instruction file {path}: {where} must be a non-empty list of non-empty strings")
    return [s.strip() for s in value]


def section(data: dict, env: str, path: Path) -> dict:
    """The ``env`` object of an instruction file's JSON ``data``, or one ValueError."""
    found = data.get(env)
    if not isinstance(found, dict):
        raise ValueError(f"instruction file {path} has no {env!r} object")
    return found


_FORMATS: dict[str, InstructionFormat] = {}


def register_instruction_format(env: str, instruction_format: InstructionFormat) -> None:
    """Makes ``env`` (and the variants named in ``instruction_format.aliases``) read its instructions this way.

    An env package calls it beside its ``register_environment`` calls; calling it again for ``env`` replaces the
    format (e.g. to read another layout of instruction file).
    """
    _FORMATS[env] = instruction_format


def instruction_envs() -> dict[str, str]:
    """Every env or variant name with instructions -> the env whose instructions it uses."""
    names = {env: env for env in _FORMATS}
    names.update({alias: env for env, fmt in _FORMATS.items() for alias in fmt.aliases})
    return names


def instruction_format(env: str) -> InstructionFormat:
    """The instruction format of an env or of one of its variants, or one clear error."""
    names = instruction_envs()
    if env not in names:
        raise ValueError(f"unknown env {env!r} for instructions; valid: {', '.join(sorted(names))}")
    return _FORMATS[names[env]]
