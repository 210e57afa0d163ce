"""CLEVR-Robot task vocabulary: colours, relations and the 80 goal ids (shared by the env and the language layer).

Goal id = pair * 4 + relation, where pair enumerates ordered (source, destination) colour pairs, source !=
destination, row-major over source then destination (0..19), and relation indexes ``RELATIONS``.
"Push the SOURCE ball RELATION the DESTINATION ball" is satisfied when SOURCE lies RELATION of DESTINATION.
Directions follow the original google-research env: front = +y, behind = -y, left = -x, right = +x.
"""

from __future__ import annotations

import numpy as np

COLORS: tuple[str, ...] = ("red", "blue", "green", "purple", "cyan")
NUM_BALLS = len(COLORS)

# name, natural-language phrase, unit vector (x, y) pointing from the destination to where the source must be
RELATIONS: tuple[tuple[str, str, tuple[float, float]], ...] = (
    ("front", "in front of", (0.0, 1.0)),
    ("behind", "behind", (0.0, -1.0)),
    ("left", "to the left of", (-1.0, 0.0)),
    ("right", "to the right of", (1.0, 0.0)),
)
NUM_RELATIONS = len(RELATIONS)
RELATION_VECTORS = np.array([vector for _, _, vector in RELATIONS], np.float32)  # (4, 2)

ORDERED_PAIRS: tuple[tuple[int, int], ...] = tuple(
    (src, dst) for src in range(NUM_BALLS) for dst in range(NUM_BALLS) if src != dst
)
NUM_GOALS = len(ORDERED_PAIRS) * NUM_RELATIONS  # 80

# goal id -> (source, destination, relation), as int32 lookup tables usable inside jit
GOAL_SOURCE = np.repeat(np.array([s for s, _ in ORDERED_PAIRS], np.int32), NUM_RELATIONS)
GOAL_DESTINATION = np.repeat(np.array([d for _, d in ORDERED_PAIRS], np.int32), NUM_RELATIONS)
GOAL_RELATION = np.tile(np.arange(NUM_RELATIONS, dtype=np.int32), len(ORDERED_PAIRS))


def goal_id(source: int, destination: int, relation: int) -> int:
    """The goal id of "push ``source`` ``relation`` ``destination``" (colour and relation indices)."""
    if source == destination:
        raise ValueError("source and destination must be different balls")
    return ORDERED_PAIRS.index((source, destination)) * NUM_RELATIONS + relation


def describe_goal(goal: int) -> str:
    """Plain-text description, e.g. ``'red ball in front of the blue ball'``."""
    phrase = RELATIONS[GOAL_RELATION[goal]][1]
    return f"{COLORS[GOAL_SOURCE[goal]]} ball {phrase} the {COLORS[GOAL_DESTINATION[goal]]} ball"
