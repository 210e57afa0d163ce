"""CLEVR-Robot: lean-physics faithfulness vs the original model in C MuJoCo, goal semantics, rewards, resets."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.clevr import tasks
from tests.clevr_reference import ORIGINAL_XML, PushSimulator

# Four balls parked in the corners, away from the action; ball 0 (red) is the one pushed.
CORNERS = [[-0.45, 0.55], [0.45, 0.55], [-0.45, -0.15], [0.45, -0.15]]
PARK = 3 * 8 + 7  # push the purple ball (parked at the bottom-left corner) into its corner: lets the others coast
AXIS_ACTIONS = [0, 1, 2, 3]  # red ball along +x, +y, -x, -y
DIAGONAL_ACTIONS = [4, 5, 6, 7]


def _scene(red=(0.0, 0.2), blue=None) -> np.ndarray:
    scene = np.array([red, *CORNERS], np.float64)
    if blue is not None:
        scene[1] = blue
    return scene


def _run(sim: PushSimulator, scene: np.ndarray, actions: list[int]) -> np.ndarray:
    """(len(actions) + 1, 5, 2) ball positions, before and after each push."""
    sim.set_balls(scene)
    return np.stack([scene] + [sim.push(a) for a in actions])


@pytest.fixture(scope="module")
def original():
    return PushSimulator(ORIGINAL_XML)


@pytest.fixture(scope="module")
def c_env():
    return envs.make("clevr", physics="c")


@pytest.fixture(scope="module")
def lean(c_env):
    return PushSimulator(model=c_env.mj_model, substeps=c_env.config.substeps)


@pytest.fixture(scope="module")
def c_step(c_env):
    return jax.jit(c_env.step)


def _state_at(env, ball_xy, goal=None, start_xy=None):
    """A reset state moved to hand-built ball positions (balls at rest), optionally with a chosen goal."""
    state = env.reset(jax.random.key(0))
    ball_xy = jnp.asarray(ball_xy, jnp.float32)
    qpos = state.data.qpos.at[:10].set(ball_xy.reshape(-1))
    task = state.task.replace(start_xy=ball_xy if start_xy is None else jnp.asarray(start_xy, jnp.float32))
    if goal is not None:
        task = task.replace(
            goal=jnp.int32(goal),
            source=jnp.int32(tasks.GOAL_SOURCE[goal]),
            destination=jnp.int32(tasks.GOAL_DESTINATION[goal]),
            relation=jnp.int32(tasks.GOAL_RELATION[goal]),
            distance=tasks.goal_distance(ball_xy, goal),
        )
    return state.replace(data=env.physics.init(qpos), obs=ball_xy.reshape(-1), task=task)


# --- physics faithfulness ------------------------------------------------------------------------------------------
def test_original_model_reproduces_reference_push_lengths(original):
    for actions, expected in ((AXIS_ACTIONS, 0.247), (DIAGONAL_ACTIONS, 0.277)):
        for action in actions:
            moved = np.linalg.norm(np.diff(_run(original, _scene(), [action])[:, 0], axis=0))
            assert moved == pytest.approx(expected, abs=0.005), (action, moved)


def test_lean_push_lengths_within_10_percent_of_original(lean):
    for actions, expected in ((AXIS_ACTIONS, 0.247), (DIAGONAL_ACTIONS, 0.277)):
        for action in actions:
            path = _run(lean, _scene(), [action, PARK])[:, 0]
            moved = np.linalg.norm(path[1] - path[0])
            assert moved == pytest.approx(expected, rel=0.10), (action, moved)
            direction = tasks.PUSH_DIRECTIONS[action % 8] / np.linalg.norm(tasks.PUSH_DIRECTIONS[action % 8])
            assert np.dot(path[1] - path[0], direction) > 0.99 * moved  # straight along the push
            assert 0.0 < np.linalg.norm(path[2] - path[1]) < 0.1  # coasts on (velocity carries over), then stops


@pytest.mark.parametrize(
    "name, red, blue, action",
    [
        ("centred", (-0.15, 0.2), (0.15, 0.2), 0),
        ("offset", (-0.15, 0.2), (0.15, 0.3), 0),
        ("diagonal", (-0.15, 0.1), (0.1, 0.32), 4),
        ("wall", (0.3, 0.2), None, 0),
    ],
)
def test_lean_matches_original_in_collisions(original, lean, name, red, blue, action):
    scene = _scene(red, blue)
    reference = _run(original, scene, [action, action, PARK])
    result = _run(lean, scene, [action, action, PARK])
    # two pushes and a coasting step: every ball within 6.5 cm of the original (a push is ~25 cm, a radius 13 cm)
    assert np.abs(result - reference).max() < 0.065, (name, result[-1], reference[-1])
    if blue is not None:  # the push is transferred: the hit ball moves a lot in both models
        assert np.linalg.norm(reference[1, 1] - scene[1]) > 0.08
        assert np.linalg.norm(result[1, 1] - scene[1]) > 0.08
    else:  # the wall stops the ball at the confinement edge
        assert abs(result[-1, 0, 0] - 0.47) < 0.02 and abs(reference[-1, 0, 0] - 0.466) < 0.01


def test_env_step_is_the_teleport_push(c_env, c_step, lean):
    scene = _scene((-0.15, 0.2), (0.15, 0.3))
    state = c_step(_state_at(c_env, scene), jnp.int32(0))
    state = c_step(state, jnp.int32(PARK))
    reference = _run(lean, scene, [0, PARK])[-1]
    np.testing.assert_allclose(np.asarray(state.obs).reshape(5, 2), reference, atol=1e-5)


# --- goal semantics ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("relation", range(tasks.NUM_RELATIONS))
def test_success_per_relation_with_distance_limit(relation):
    goal = tasks.goal_id(0, 1, relation)  # red RELATION of blue
    blue = np.array([0.0, 0.2])
    unit = tasks.RELATION_VECTORS[relation]
    perpendicular = np.array([-unit[1], unit[0]])

    def success(red):
        return bool(tasks.goal_success(jnp.asarray(np.array([red, blue, *CORNERS[1:]]), jnp.float32), goal))

    assert success(blue + 0.3 * unit)
    assert success(blue + 0.28 * unit + 0.22 * perpendicular)  # 38 degrees off-axis, distance 0.356
    assert not success(blue + 0.3 * unit + 0.25 * perpendicular)  # 40 degrees off-axis but distance 0.3905
    assert not success(blue + 0.45 * unit)  # right sector, too far (>= 0.39)
    assert not success(blue + 0.2 * unit + 0.25 * perpendicular)  # 51 degrees off-axis: the neighbouring sector
    for other in range(tasks.NUM_RELATIONS):
        if other != relation:
            assert not success(blue + 0.3 * tasks.RELATION_VECTORS[other])


def test_sectors_are_half_open_and_follow_front_is_plus_y():
    offsets = jnp.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0], [0, 1], [0, -1], [-1, 0], [1, 0]])
    # 45 deg -> front, 135 -> left, 225 -> behind, 315 -> right (each sector is [start, start + 90))
    np.testing.assert_array_equal(tasks.relation_of(offsets), [0, 2, 1, 3, 0, 1, 2, 3])
    assert tasks.RELATIONS[0][0] == "front" and tuple(tasks.RELATION_VECTORS[0]) == (0.0, 1.0)


def test_reward_sign_success_and_failure_values():
    assert float(tasks.goal_reward(0.5, 0.4, False, False)) == pytest.approx(1.0)
    assert float(tasks.goal_reward(0.4, 0.5, False, False)) == pytest.approx(-1.0)
    assert float(tasks.goal_reward(0.4, 0.5, True, False)) == 100.0
    assert float(tasks.goal_reward(0.4, 0.3, False, True)) == -10.0
    ball_xy = jnp.asarray(_scene((0.0, 0.5), (0.0, 0.0)), jnp.float32)  # red 0.5 in front of blue
    expected = np.linalg.norm([0.0, 0.5 - 0.195])
    assert float(tasks.goal_distance(ball_xy, tasks.goal_id(0, 1, 0))) == pytest.approx(expected, abs=1e-6)


def test_env_success_pays_100_and_terminates(c_env, c_step):
    goal = tasks.goal_id(0, 1, 0)  # red in front of blue
    state = _state_at(c_env, _scene((0.0, 0.55), (0.0, 0.05)), goal)  # 0.5 apart: front sector, too far
    assert float(tasks.goal_success(state.obs.reshape(5, 2), goal)) == 0.0
    state = c_step(state, jnp.int32(3))  # push red along -y: it ends ~0.25 closer
    assert float(state.metrics["success"]) == 1.0 and float(state.done) == 1.0 and float(state.reward) == 100.0
    # a push away from the target: negative dense reward, no termination
    state = c_step(_state_at(c_env, _scene((0.0, 0.55), (0.0, 0.05)), tasks.goal_id(0, 1, 1)), jnp.int32(1))
    assert float(state.reward) < 0.0 and float(state.done) == 0.0


def test_displacement_failure_option(c_env, c_step):
    fail_env = envs.make("clevr", physics="c", fail_on_displacement=True)
    goal = tasks.goal_id(0, 1, 0)  # source red; pushing blue (a non-source ball) by ~0.25 m fails
    scene = _scene((-0.3, 0.4), (0.1, 0.05))
    failed = jax.jit(fail_env.step)(_state_at(fail_env, scene, goal), jnp.int32(9))  # blue along +y
    assert float(failed.done) == 1.0 and float(failed.reward) == -10.0 and float(failed.metrics["failure"]) == 1.0
    default = c_step(_state_at(c_env, scene, goal), jnp.int32(9))
    assert float(default.done) == 0.0 and float(default.reward) != -10.0
    moved_source = jax.jit(fail_env.step)(_state_at(fail_env, scene, goal), jnp.int32(2))  # push red itself
    assert float(moved_source.done) == 0.0


def test_collect_action_type_pushes_the_source_ball(c_env, c_step):
    collect_env = envs.make("clevr", physics="c", action_type="collect")
    assert collect_env.action_spec.size == 8 and c_env.action_spec.size == 40
    goal = tasks.goal_id(2, 1, 0)  # source green: collect action k is the 40-way push 2 * 8 + k
    scene = _scene((-0.3, 0.4), (0.1, 0.05))
    state = _state_at(collect_env, scene, goal)
    pushed = jax.jit(collect_env.step)(state, jnp.int32(1))
    reference = c_step(_state_at(c_env, scene, goal), jnp.int32(2 * 8 + 1))
    np.testing.assert_allclose(np.asarray(pushed.obs), np.asarray(reference.obs), atol=1e-6)
    assert int(collect_env.push_action(state, jnp.int32(1))) == 17
    with pytest.raises(ValueError, match=r"valid actions are 0\.\.7"):
        collect_env.step(state, jnp.int32(8))
    with pytest.raises(ValueError, match="needs task='goal'"):
        envs.make("clevr-arrangement", action_type="collect")
    with pytest.raises(ValueError, match="unknown action_type"):
        envs.make("clevr", action_type="continuous")


# --- resets --------------------------------------------------------------------------------------------------------
def test_reset_validity(c_env):
    states = jax.jit(jax.vmap(c_env.reset))(jax.random.split(jax.random.key(7), 2048))
    ball_xy = np.asarray(states.obs).reshape(-1, 5, 2)
    assert np.all(ball_xy >= tasks.REGION_LOW - 1e-6) and np.all(ball_xy <= tasks.REGION_HIGH + 1e-6)
    gaps = np.linalg.norm(ball_xy[:, :, None] - ball_xy[:, None], axis=-1) + 10 * np.eye(5)
    assert gaps.min() >= tasks.MIN_SEPARATION - 1e-6
    goals = np.asarray(states.task.goal)
    assert not np.any(jax.vmap(tasks.goal_success)(jnp.asarray(ball_xy), jnp.asarray(goals)))
    assert len(np.unique(goals)) == tasks.NUM_GOALS
    np.testing.assert_array_equal(states.task.source, tasks.GOAL_SOURCE[goals])
    np.testing.assert_array_equal(states.task.relation, tasks.GOAL_RELATION[goals])
    np.testing.assert_allclose(states.task.start_xy, ball_xy)
    # spread over the whole region (both corners reached), not the fallback layout
    assert ball_xy[..., 0].min() < -0.44 and ball_xy[..., 0].max() > 0.44 and ball_xy[..., 1].max() > 0.54
    on_fallback_grid = np.all(np.isin(np.round(ball_xy[..., 1], 4), np.float32([-0.1, 0.45]).round(4)), axis=1)
    assert on_fallback_grid.mean() < 0.01
    np.testing.assert_allclose(states.data.qvel, 0.0)


def test_goals_are_named_by_their_descriptions(c_env):
    assert c_env.goal_names == tasks.GOAL_NAMES and len(set(tasks.GOAL_NAMES)) == tasks.NUM_GOALS
    goal = tasks.goal_id(2, 4, 3)  # green right of cyan
    assert tasks.GOAL_NAMES[goal] == tasks.describe_goal(goal) == "green ball to the right of the cyan ball"
    task = c_env.reset(jax.random.key(0), goal="Green ball to the right of the cyan ball").task
    assert (int(task.goal), int(task.source), int(task.destination), int(task.relation)) == (goal, 2, 4, 3)
    with pytest.raises(ValueError, match=r"goal 80 is out of range for ClevrEnv; give an id in 0\.\.79"):
        c_env.reset(jax.random.key(0), goal=80)
    arrangement = envs.make("clevr-arrangement", physics="c")
    assert arrangement.goal_names == ("arrangement",) and arrangement.num_goals == 1
    with pytest.raises(ValueError, match=r"goal 1 is out of range for ClevrEnv; give an id in 0\.\.0"):
        arrangement.reset(jax.random.key(0), goal=1)


def test_goal_sampling_skips_satisfied_goals():
    ball_xy = jnp.asarray(_scene((0.0, 0.5), (0.0, 0.15)), jnp.float32)  # red in front of blue, 0.35 apart
    satisfied = np.flatnonzero(tasks.all_goals_success(ball_xy))
    assert tasks.goal_id(0, 1, 0) in satisfied and tasks.goal_id(1, 0, 1) in satisfied
    goals = jax.vmap(tasks.sample_goal, in_axes=(0, None))(jax.random.split(jax.random.key(1), 4000), ball_xy)
    assert not np.isin(np.asarray(goals), satisfied).any()
    assert len(np.unique(goals)) == tasks.NUM_GOALS - len(satisfied)


# --- arrangement ---------------------------------------------------------------------------------------------------
ARRANGED = [[-0.05, 0.5], [0.35, -0.15], [0.45, 0.45], [-0.45, 0.5], [0.1, 0.15]]  # red blue green purple cyan


def test_arrangement_constraints_on_hand_built_states():
    arranged = jnp.asarray(ARRANGED, jnp.float32)
    assert bool(jnp.all(tasks.arrangement_satisfied(arranged)))
    swapped = arranged[jnp.array([2, 1, 0, 3, 4])]  # red <-> green: red no longer left of green, cyan not left of green
    np.testing.assert_array_equal(tasks.arrangement_satisfied(swapped), [True, True, False, True, True, False])
    low_blue = arranged.at[1].set(jnp.array([0.35, 0.6]))  # blue above both: constraints 1, 2 fail
    np.testing.assert_array_equal(tasks.arrangement_satisfied(low_blue)[:2], [False, False])


def test_arrangement_env_reward_counts_constraints_and_terminates():
    env = envs.make("clevr-arrangement", physics="c")
    assert env.num_goals == 1 and env.observation_size == 10
    step = jax.jit(env.step)
    state = step(_state_at(env, ARRANGED), jnp.int32(3 * 8 + 2))  # push purple into the left wall: all 6 still hold
    assert float(state.reward) == 6.0 and float(state.done) == 1.0 and float(state.metrics["success"]) == 1.0
    state = step(_state_at(env, np.array(ARRANGED)[[2, 1, 0, 3, 4]]), jnp.int32(3 * 8 + 2))
    count = float(jnp.sum(tasks.arrangement_satisfied(state.obs.reshape(5, 2))))
    assert float(state.reward) == count < 6.0 and float(state.done) == 0.0
