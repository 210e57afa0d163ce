"""Goal ids from what a person types: an id (an int, or its digits as a string) or a goal's name.

The rule behind ``Env.goal_id``, the one public way to turn a goal into an id (``Env.reset`` and the Gymnasium
adapters call it; ``env.goal_names`` lists the names). Names match without regard to case, surrounding spaces, or
``_`` / ``-`` written for a space (``"Top_Burner"`` is ``"top burner"``). ``resolve_goal`` serves ``Env.goal_id`` and
env modules that name their goals before any env is built (the kitchen's ``tasks.task_id``).
"""

from __future__ import annotations

import numbers
import re
from collections.abc import Sequence

_SHOWN_NAMES = 8  # an error lists every name up to this many, else two of them (CLEVR has 80)


def normalise_goal_name(name: str) -> str:
    """The form names are compared in: lower case, ``_`` and ``-`` as spaces, single spaces, stripped."""
    return " ".join(re.sub(r"[_-]", " ", name).lower().split())


def describe_valid_goals(names: Sequence[str], num_goals: int) -> str:
    """What a goal may be, for an error message (one line)."""
    ids = f"an id in 0..{num_goals - 1}"
    if not names:
        return ids
    if len(names) <= _SHOWN_NAMES:
        return f"{ids} or one of the names {', '.join(map(repr, names))}"
    return f"{ids} or a name such as {names[0]!r} or {names[1]!r} (all {len(names)} in goal_names)"


def resolve_goal(goal: object, names: Sequence[str] = (), num_goals: int | None = None, where: str = "") -> int:
    """The goal id meant by ``goal``: an int (or numpy integer) in [0, num_goals), a string of digits, or one of
    ``names`` (the name of each goal id). ``num_goals`` defaults to ``len(names)``; ``where`` names the env in the
    error. Raises one ``ValueError`` line naming the valid range and names."""
    num_goals = len(names) if num_goals is None else num_goals
    text = f" for {where}" if where else ""
    valid = describe_valid_goals(names, num_goals)
    if isinstance(goal, str):
        wanted = normalise_goal_name(goal)
        if re.fullmatch(r"-?\d+", wanted):
            goal = int(wanted)
        else:
            for goal_id, name in enumerate(names):
                if normalise_goal_name(name) == wanted:
                    return goal_id
            raise ValueError(f"unknown goal {goal!r}{text}; give {valid}")
    if isinstance(goal, bool) or not isinstance(goal, numbers.Integral):
        raise ValueError(f"goal {goal!r}{text} is neither an int nor a name; give {valid}")
    if not 0 <= goal < num_goals:
        raise ValueError(f"goal {goal} is out of range{text}; give {valid}")
    return int(goal)
