"""CLEVR-Robot task vocabulary: colours, relations and the 80 goal ids (shared by the env and the language layer).

Goal id = pair * 4 + relation, where pair enumerates ordered (source, destination) colour pairs, source !=
destination, row-major over source then destination (0..19), and relation indexes ``RELATIONS``.
"Push the SOURCE ball RELATION the DESTINATION ball" is satisfied when SOURCE lies RELATION of DESTINATION.
Directions follow the original google-research env: front = +y, behind = -y, left = -x, right = +x.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
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


GOAL_NAMES: tuple[str, ...] = tuple(describe_goal(goal) for goal in range(NUM_GOALS))
"""The name of each goal id (its description): what ``ClevrEnv.goal_names`` lists and ``reset`` accepts."""


# --- pushing (spec section 2.1): action a pushes ball a // 8 in direction a % 8 -------------------------------------
NUM_DIRECTIONS = 8
NUM_ACTIONS = NUM_BALLS * NUM_DIRECTIONS  # 40
# force per axis (N) of each direction: +x, +y, -x, -y, then the four diagonals at 0.8 per axis
PUSH_DIRECTIONS = np.array(
    [[1, 0], [0, 1], [-1, 0], [0, -1], [0.8, 0.8], [-0.8, 0.8], [0.8, -0.8], [-0.8, -0.8]], np.float32
)
PUSH_OFFSET = 0.15  # the pusher starts 0.15 * direction behind the ball centre

# --- success, reward, sampling: pure JAX functions (the env composes them) ------------------------------------------
SUCCESS_DISTANCE = 0.39  # 3 radii: the source must be this close to the destination (TALAR)
TARGET_OFFSET = SUCCESS_DISTANCE / 2  # the dense reward pulls the source to destination + 0.195 * u_relation
FAIL_DISTANCE = 0.2  # optional failure: a non-source ball displaced this far from its episode-start position
MIN_SEPARATION = 0.36  # centre distance between balls at reset (surface gap 0.1)
# reachable ball centres (wall - radius): x in [-0.47, 0.47], y in [-0.17, 0.57]
REGION_LOW = np.array([-0.47, -0.17], np.float32)
REGION_HIGH = np.array([0.47, 0.57], np.float32)

# Appendix D.1.3 "arrangement": the 6 geometrically distinct constraints (source, destination, relation), front = +y
ARRANGEMENT_CONSTRAINTS = np.array(
    [
        [0, 1, 0],  # red in front of blue
        [2, 1, 0],  # green in front of blue
        [0, 2, 2],  # red to the left of green
        [3, 4, 2],  # purple to the left of cyan
        [3, 0, 2],  # purple to the left of red
        [4, 2, 2],  # cyan to the left of green
    ],
    np.int32,
)


# The paper lists ten constraints (Appendix D.1.3); several coincide: (4) = (5) = (9), (2) = (7), (6) = (10).
# Index into ARRANGEMENT_CONSTRAINTS of each listed constraint, in the paper's order (1)..(10).
ARRANGEMENT_LISTED = np.array([4, 2, 5, 3, 3, 0, 2, 1, 3, 0], np.int32)
ARRANGEMENT_REWARDS: tuple[str, ...] = ("distinct", "listed")


def relation_of(offset: jax.Array) -> jax.Array:
    """The relation index (0 front, 1 behind, 2 left, 3 right) whose sector holds ``offset`` = source - destination.

    Sectors are half-open 90-degree wedges centred on the relation's axis: front [45, 135), left [135, 225),
    behind [225, 315), right [315, 360) + [0, 45) degrees CCW from +x. Components with |.| < 1e-3 count as 0.

    Args:
        offset: (..., 2) source minus destination centre.

    Returns:
        (...,) int32 relation index.
    """
    offset = jnp.where(jnp.abs(offset) < 1e-3, 0.0, offset)
    angle = jnp.mod(jnp.degrees(jnp.arctan2(offset[..., 1], offset[..., 0])), 360.0)
    quadrant = jnp.floor(jnp.mod(angle - 45.0, 360.0) / 90.0).astype(jnp.int32)  # 0 front, 1 left, 2 behind, 3 right
    return jnp.array([0, 2, 1, 3], jnp.int32)[jnp.clip(quadrant, 0, 3)]


def relation_holds(
    source_xy: jax.Array, destination_xy: jax.Array, relation: jax.Array, max_distance: float | None = None
) -> jax.Array:
    """Whether the source lies ``relation`` of the destination (sector test, optionally closer than ``max_distance``).

    Args:
        source_xy, destination_xy: (..., 2) ball centres.
        relation: (...,) relation index.
        max_distance: centre-distance limit (strict), or None for no limit (the arrangement task).

    Returns:
        (...,) bool.
    """
    offset = source_xy - destination_xy
    holds = relation_of(offset) == relation
    if max_distance is not None:
        holds = holds & (jnp.linalg.norm(offset, axis=-1) < max_distance)
    return holds


def _goal_parts(goal: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(source, destination, relation) of a (possibly traced) goal id."""
    return jnp.asarray(GOAL_SOURCE)[goal], jnp.asarray(GOAL_DESTINATION)[goal], jnp.asarray(GOAL_RELATION)[goal]


def goal_success(ball_xy: jax.Array, goal: jax.Array) -> jax.Array:
    """Whether goal ``goal`` holds for balls at ``ball_xy`` (5, 2): right sector and centre distance < 0.39."""
    source, destination, relation = _goal_parts(goal)
    return relation_holds(ball_xy[source], ball_xy[destination], relation, SUCCESS_DISTANCE)


def all_goals_success(ball_xy: jax.Array) -> jax.Array:
    """(80,) bool, ``goal_success`` for every goal id."""
    return relation_holds(ball_xy[GOAL_SOURCE], ball_xy[GOAL_DESTINATION], GOAL_RELATION, SUCCESS_DISTANCE)


def goal_distance(ball_xy: jax.Array, goal: jax.Array) -> jax.Array:
    """Distance from the source ball to the target point destination + 0.195 * u_relation (the dense-reward term)."""
    source, destination, relation = _goal_parts(goal)
    target = ball_xy[destination] + TARGET_OFFSET * jnp.asarray(RELATION_VECTORS)[relation]
    return jnp.linalg.norm(ball_xy[source] - target)


def displacement_failure(ball_xy: jax.Array, start_xy: jax.Array, source: jax.Array) -> jax.Array:
    """Whether a ball other than ``source`` moved more than 0.2 from its episode-start position (optional failure)."""
    moved = jnp.linalg.norm(ball_xy - start_xy, axis=-1) > FAIL_DISTANCE
    return jnp.any(moved & (jnp.arange(NUM_BALLS) != source))


def goal_reward(previous_distance: jax.Array, distance: jax.Array, success: jax.Array, failure: jax.Array) -> jax.Array:
    """10 * (d_prev - d_now); +100 on success (replaces it); -10 on failure (if no success)."""
    dense = 10.0 * (previous_distance - distance)
    return jnp.where(success, 100.0, jnp.where(failure, -10.0, dense)).astype(jnp.float32)


def arrangement_satisfied(ball_xy: jax.Array) -> jax.Array:
    """(6,) bool, each arrangement constraint's sector test (no distance limit)."""
    c = jnp.asarray(ARRANGEMENT_CONSTRAINTS)
    return relation_holds(ball_xy[c[:, 0]], ball_xy[c[:, 1]], c[:, 2])


def _place_balls_sequentially(rng: jax.Array, pool_size: int) -> tuple[jax.Array, jax.Array]:
    """One attempt of sequential rejection sampling from a stream of ``pool_size`` uniform points.

    Ball i takes the first point of the stream at >= 0.36 from every ball placed before it (the original's
    per-ball rejection sampling, with a finite stream instead of retries).

    Returns:
        ((5, 2) float32 centres, () bool whether every ball found a point).
    """
    low, high = jnp.asarray(REGION_LOW), jnp.asarray(REGION_HIGH)
    bits = jax.random.bits(rng, (pool_size,), jnp.uint32)  # one 32-bit word -> two 16-bit coordinates (RNG is the cost)
    unit = jnp.stack([bits & 0xFFFF, bits >> 16], axis=-1).astype(jnp.float32) / 65536.0
    pool = low + (high - low) * unit
    free = jnp.ones(pool_size, bool)
    placed, ok = [], jnp.bool_(True)
    for _ in range(NUM_BALLS):  # unrolled: 5 small vector steps
        choice = jnp.argmax(free)
        ok = ok & free[choice]
        placed.append(pool[choice])
        free = free & (jnp.linalg.norm(pool - pool[choice], axis=-1) >= MIN_SEPARATION)
    return jnp.stack(placed), ok


def sample_ball_positions(rng: jax.Array, num_attempts: int = 8, pool_size: int = 64) -> jax.Array:
    """Balls uniform in the reachable region with centre distances >= 0.36, in fixed shapes.

    Like the original's sampler (per-ball rejection, whole-scene restarts when stuck): ``num_attempts``
    independent sequential attempts over streams of ``pool_size`` points run side by side and the first complete
    one is kept (one attempt jams 27% of the time, so all 8 fail with probability ~3e-5); then a fixed valid layout
    (shuffled) is the fallback.

    Returns:
        (5, 2) float32 ball centres.
    """
    rng_attempts, rng_fallback = jax.random.split(rng)
    attempts = jax.random.split(rng_attempts, num_attempts)
    scenes, complete = jax.vmap(_place_balls_sequentially, in_axes=(0, None))(attempts, pool_size)
    grid = jnp.array([[-0.4, -0.1], [0.0, -0.1], [0.4, -0.1], [-0.2, 0.45], [0.2, 0.45]], jnp.float32)
    fallback = grid[jax.random.permutation(rng_fallback, NUM_BALLS)]
    return jnp.where(jnp.any(complete), scenes[jnp.argmax(complete)], fallback)


def sample_goal(rng: jax.Array, ball_xy: jax.Array) -> jax.Array:
    """A goal id uniform over the 80 goals, resampled until it does not already hold (= uniform over unmet goals).

    At least 60 goals are always unmet (each ordered pair satisfies at most one of its 4 relations).
    """
    unmet = ~all_goals_success(ball_xy)
    pick = jax.random.randint(rng, (), 0, jnp.sum(unmet))  # the pick-th unmet goal: one random number, not 80
    return jnp.argmax(jnp.cumsum(unmet) > pick).astype(jnp.int32)
