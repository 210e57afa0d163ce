"""Chains of sub-tasks in one episode: ``Env.retarget``, ``talar_jax.chains`` and ``experiments.chains``."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.clevr import tasks as clevr_tasks
from envs.kitchen import tasks
from envs.kitchen.scripted import scripted_action
from envs.wrappers import EpisodeWrapper
from experiments import chains as chains_command
from talar_jax.agent import load
from talar_jax.chains import ChainResult, chain_episode, run_chains
from tests.helpers import one_line_error


def assert_trees_equal(a, b):
    leaves_a, tree_a = jax.tree.flatten(a)
    leaves_b, tree_b = jax.tree.flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# --- Env.retarget ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("goal_observation", [False, True])
def test_kitchen_retarget_of_a_reset_state_is_the_reset_of_that_goal(goal_observation):
    env = envs.make("kitchen", physics="c", goal_observation=goal_observation)
    key = jax.random.key(3)
    assert_trees_equal(env.retarget(env.reset(key, 0), 4), env.reset(key, 4))
    assert_trees_equal(env.retarget(env.reset(key, 5), "light switch"), env.reset(key, 2))


def test_kitchen_retarget_keeps_the_physics_and_the_progress():
    env = envs.make("kitchen", physics="c", goal_observation=True)
    step = jax.jit(env.step)
    state = env.reset(jax.random.key(0), 0)
    for i in range(30):
        state = step(state, scripted_action(state.obs, jnp.int32(0), jnp.int32(i)))
    moved = env.retarget(state, 3)
    assert_trees_equal(moved.data, state.data)
    for field in ("completed", "distance", "robot_qpos_obs", "noise_rng"):
        np.testing.assert_array_equal(getattr(moved.task, field), getattr(state.task, field))
    np.testing.assert_array_equal(moved.obs[:30], state.obs[:30])
    np.testing.assert_array_equal(moved.obs[30:], np.eye(6)[3])
    assert int(moved.task.goal) == 3 and float(moved.done) == 0.0
    assert float(moved.metrics["distance"]) == pytest.approx(float(state.task.distance[3]))
    action = jnp.full((9,), 0.3)
    assert_trees_equal(step(moved, action).data, step(state, action).data)  # the goal never reaches the physics


def _clevr_key_where_neither_holds(env, goals):
    """A key whose first ball layout meets none of ``goals`` (so reset draws it for each of them)."""
    for seed in range(50):
        key = jax.random.key(seed)
        ball_xy = clevr_tasks.sample_ball_positions(jax.random.split(key)[0])
        if not any(bool(clevr_tasks.goal_success(ball_xy, g)) for g in goals):
            return key
    raise AssertionError("no such key in 50")


@pytest.mark.parametrize("goal_observation", [False, True])
def test_clevr_retarget_of_a_reset_state_is_the_reset_of_that_goal(goal_observation):
    env = envs.make("clevr", physics="c", goal_observation=goal_observation)
    key = _clevr_key_where_neither_holds(env, (7, 42))
    assert_trees_equal(env.retarget(env.reset(key, 7), 42), env.reset(key, 42))


def test_clevr_retarget_starts_the_goal_from_where_the_balls_are():
    env = envs.make("clevr", physics="c", goal_observation=True, fail_on_displacement=True)
    step = jax.jit(env.step)
    state = env.reset(jax.random.key(1), 7)
    for action in (3, 11, 19, 27, 35):
        state = step(state, action)
    moved = env.retarget(state, 42)
    ball_xy = np.asarray(state.data.qpos[:10]).reshape(5, 2)
    assert_trees_equal(moved.data, state.data)
    np.testing.assert_array_equal(moved.task.start_xy, ball_xy)
    assert float(moved.task.distance) == pytest.approx(float(clevr_tasks.goal_distance(ball_xy, 42)))
    source, destination, relation = (int(getattr(moved.task, f)) for f in ("source", "destination", "relation"))
    assert (source, destination, relation) == tuple(
        int(t[42]) for t in (clevr_tasks.GOAL_SOURCE, clevr_tasks.GOAL_DESTINATION, clevr_tasks.GOAL_RELATION)
    )
    np.testing.assert_array_equal(moved.obs, np.concatenate([ball_xy.reshape(-1), env.goal_features(moved.task)]))
    assert float(moved.done) == 0.0 and float(moved.reward) == 0.0
    assert_trees_equal(step(moved, 12).data, step(state, 12).data)


def test_retarget_is_jit_and_vmap_able_and_flags_a_traced_goal_out_of_range():
    env = envs.make("clevr", physics="c")
    states = jax.vmap(lambda k: env.reset(k, 5))(jax.random.split(jax.random.key(0), 3))
    goals = jnp.array([1, 79, 80])
    moved = jax.jit(jax.vmap(env.retarget))(states, goals)
    for i in range(2):
        one = env.retarget(jax.tree.map(lambda x, i=i: x[i], states), int(goals[i]))
        assert_trees_equal(jax.tree.map(lambda x, i=i: x[i], moved), one)
    assert np.isnan(np.asarray(moved.obs[2])).all() and not np.isnan(np.asarray(moved.obs[:2])).any()


def test_retarget_refuses_envs_without_a_goal_and_goals_out_of_range():
    for name in ("kitchen-all", "clevr-arrangement"):
        env = envs.make(name, physics="c")
        with pytest.raises(NotImplementedError, match="no goal to retarget"):
            env.retarget(env.reset(jax.random.key(0)), 0)
    env = envs.make("kitchen", physics="c")
    with pytest.raises(ValueError, match="goal"):
        env.retarget(env.reset(jax.random.key(0), 0), 6)


def test_a_retarget_through_the_episode_wrapper_starts_a_new_time_limit():
    env = EpisodeWrapper(envs.make("clevr", physics="c"), episode_length=50)
    state = env.reset(jax.random.key(0), 3)
    for action in (0, 8, 16):
        state = env.step(state, action)
    assert int(state.info["steps"]) == 3
    moved = env.retarget(state, 9)
    assert int(moved.info["steps"]) == 0 and int(moved.task.goal) == 9


# --- starting from the scenes a chain leaves ------------------------------------------------------------------
def test_kitchen_others_done_start_sets_other_sub_tasks_done_and_keeps_the_goal_draw():
    keys = jax.random.split(jax.random.key(0), 16)

    def resets(**options):
        env = envs.make("kitchen", physics="c", **options)
        return jax.jit(jax.vmap(env.reset))(keys)

    today = resets()
    assert_trees_equal(resets(start="others_done", start_done_probability=0.0), today)
    everything = resets(start="others_done", start_done_probability=1.0)
    np.testing.assert_array_equal(everything.task.goal, today.task.goal)
    done = np.asarray(everything.task.distance) < 0.3
    goal_done = done[np.arange(16), np.asarray(everything.task.goal)]
    assert not goal_done.any() and done.sum(1).tolist() == [5] * 16
    half = np.asarray(resets(start="others_done").task.distance) < 0.3
    assert 0 < half.sum() < 5 * 16
    np.testing.assert_array_equal(everything.obs[:, :9], today.obs[:, :9])  # the arm starts where it always does


def test_kitchen_after_subtask_start_puts_the_arm_where_a_done_sub_task_ends():
    keys = jax.random.split(jax.random.key(1), 16)
    options = {"physics": "c", "start_done_probability": 1.0, "noise_ratio": 0.0}
    others = jax.jit(jax.vmap(envs.make("kitchen", start="others_done", **options).reset))(keys)
    after = jax.jit(jax.vmap(envs.make("kitchen", start="after_subtask", **options).reset))(keys)
    np.testing.assert_array_equal(after.task.goal, others.task.goal)
    np.testing.assert_array_equal(after.obs[:, 9:], others.obs[:, 9:])  # the same objects done
    postures = tasks.posture_targets("scripted")
    gap = np.abs(np.asarray(after.obs[:, None, :7]) - postures[None, :, :7]).max(-1)  # (16, 6)
    nearest = gap.argmin(1)
    assert (gap.min(1) <= 0.1 + 1e-4).all()  # within start_arm_noise of a scripted posture at success
    assert (nearest != np.asarray(after.task.goal)).all()  # never the goal's own: it is not done
    assert len(set(nearest.tolist())) > 2
    still = envs.make("kitchen", start="after_subtask", start_arm_noise=0.0, **options)
    exact = np.abs(np.asarray(jax.jit(jax.vmap(still.reset))(keys).obs[:, None, :9]) - postures[None]).max(-1)
    assert (exact.min(1) < 5e-3).all()  # exact but for finger openings a hair outside their range, clipped
    none_done = envs.make("kitchen", start="after_subtask", **{**options, "start_done_probability": 0.0})
    np.testing.assert_allclose(
        np.asarray(jax.jit(jax.vmap(none_done.reset))(keys).obs[:, :9]), others.obs[:, :9], atol=0.1 + 1e-4
    )


def test_kitchen_start_arm_draws_the_recorded_endings_and_keeps_the_scripted_draws():
    """'ended' puts the arm at a recorded ending of a done sub-task (the shipped file), 'either' at one of the two,
    and 'scripted' (the default) draws exactly what it drew before the option existed."""
    from envs.kitchen.env import ENDED_POSTURES_FILE, POS_HIGH, POS_LOW

    keys = jax.random.split(jax.random.key(2), 32)
    options = {"physics": "c", "start": "after_subtask", "start_done_probability": 1.0, "noise_ratio": 0.0}
    # (6, K, 9), clipped as the env clips a start: a pushed arm can end a hair outside its servo range
    endings = np.clip(np.load(ENDED_POSTURES_FILE)["postures"], POS_LOW, POS_HIGH)
    scripted = tasks.posture_targets("scripted")

    def arms(**extra):
        env = envs.make("kitchen", **options, start_arm_noise=0.0, **extra)
        return np.asarray(jax.jit(jax.vmap(env.reset))(keys).obs[:, :9])

    def nearest(arm, postures):  # the max-joint gap to the nearest of (..., 9) postures
        return np.abs(arm[:, None] - postures.reshape(1, -1, 9)).max(-1).min(-1)

    ended, either, default = arms(start_arm="ended"), arms(start_arm="either"), arms()
    assert (nearest(ended, endings) < 5e-3).all()
    assert (nearest(ended, scripted) > 0.05).mean() > 0.8  # the endings are not the scripted postures
    from_endings = nearest(either, endings) < 5e-3
    assert 0 < from_endings.sum() < len(keys) and (nearest(either[~from_endings], scripted) < 5e-3).all()
    np.testing.assert_array_equal(default, arms(start_arm="scripted"))
    assert (nearest(default, scripted) < 5e-3).all()
    with pytest.raises(ValueError, match="start_arm"):
        envs.make("kitchen", physics="c", start_arm="anywhere")


def test_every_kitchen_sub_task_can_be_done_with_all_the_others_done():
    """The 'others_done' start is a kitchen a task can still be done in: the scripted controller does each sub-task
    with the five others already done (nothing in the way, no object knocked out of place)."""
    env = envs.make("kitchen", physics="c", start="others_done", start_done_probability=1.0, noise_ratio=0.0)

    def episode(key, goal):
        def step(carry, i):
            state, done = carry
            stepped = env.step(state, scripted_action(state.obs, goal, i))
            return (stepped, done | (stepped.metrics["success"] > 0.5)), None

        (_, done), _ = jax.lax.scan(step, (env.reset(key, goal), jnp.bool_(False)), jnp.arange(env.episode_length))
        return done

    goals = jnp.arange(env.num_goals)
    assert np.asarray(jax.jit(jax.vmap(episode))(jax.random.split(jax.random.key(0), env.num_goals), goals)).all()


def test_clevr_after_goal_start_moves_one_ball_beside_another():
    keys = jax.random.split(jax.random.key(0), 16)
    today = jax.jit(jax.vmap(envs.make("clevr", physics="c").reset))(keys)
    env = envs.make("clevr", physics="c", start="after_goal")
    after = jax.jit(jax.vmap(lambda key: env.reset(key, 17)))(keys)
    before_xy, after_xy = (np.asarray(s.obs).reshape(-1, 5, 2) for s in (today, after))
    same_draw = np.asarray(jax.jit(jax.vmap(lambda key: env.reset(key)))(keys).obs).reshape(-1, 5, 2)
    moved = (np.abs(same_draw - before_xy) > 0).any(-1).sum(1)
    assert set(moved.tolist()) <= {0, 1} and moved.sum() > 8  # one ball moved in most scenes, the rest as drawn
    gaps = np.linalg.norm(after_xy[:, :, None] - after_xy[:, None], axis=-1) + 9 * np.eye(5)
    assert gaps.min() >= 0.3 - 1e-6
    assert not any(bool(clevr_tasks.goal_success(xy, 17)) for xy in after_xy)  # the episode's own goal still to do


@pytest.mark.parametrize(
    ("name", "options", "message"),
    [
        ("kitchen", {"start": "anywhere"}, "start"),
        ("kitchen", {"start_done_probability": 1.5}, "start_done_probability"),
        ("kitchen", {"start_arm_noise": -0.1}, "start_arm_noise"),
        ("clevr", {"start": "others_done"}, "start"),
    ],
)
def test_start_options_are_checked(name, options, message):
    with pytest.raises(ValueError, match=message):
        envs.make(name, physics="c", **options)


# --- ChainResult ----------------------------------------------------------------------------------------------
def test_chain_result_counts_clauses_in_a_row_as_calvin_does():
    reached = np.array([[3, 9, 20], [4, -1, -1], [-1, -1, -1], [2, 5, -1]])
    env_step = np.array([[3, 9, 20], [4, -1, -1], [-1, -1, -1], [2, 5, -1]])
    language = np.array([[1, 9, -1], [4, 30, -1], [-1, -1, -1], [2, 7, -1]])
    result = ChainResult(np.zeros((4, 3), np.int32), reached, env_step, language, "env", True, 50)
    np.testing.assert_array_equal(result.completed, [3, 1, 0, 2])
    assert result.success_at == [0.75, 0.5, 0.25]
    assert result.average_length == 1.5
    np.testing.assert_array_equal(result.attempted.sum(1), [3, 2, 1, 3])
    agreement = result.agreement()
    # begun clauses: 9; both tests agree on done-or-not in all but (0, 2) and (1, 1)
    assert agreement["clauses"] == 9 and agreement["reached"] == pytest.approx(7 / 9)
    assert agreement["same_step"] == pytest.approx(5 / 9)
    assert result.summary() == {"length": 3, "chains": 4, "success_at": [0.75, 0.5, 0.25], "average_length": 1.5}
    no_language = ChainResult(np.zeros((4, 3), np.int32), reached, env_step, language * 0 - 1, "env", False, 50)
    assert no_language.agreement() is None
    np.testing.assert_array_equal(result.confirmed, result.completed)
    goals = np.array([[0, 1, 2], [1, 0, 2], [2, 1, 0], [0, 2, 1]])
    begun, reached = dataclasses.replace(result, goals=goals).transitions(3)
    # row 3: first clauses (from the reset); chain 1 failed 0 after 1, chain 2 its first clause (2), chain 3 1 after 2
    np.testing.assert_array_equal(begun, [[0, 1, 1], [1, 0, 1], [0, 1, 0], [2, 1, 1]])
    np.testing.assert_array_equal(reached, [[0, 1, 1], [0, 0, 1], [0, 0, 0], [2, 1, 0]])


# --- run_chains with a scripted policy --------------------------------------------------------------------------
class ScriptedClevrAgent:
    """An agent-shaped scripted pusher: its code is a one-hot of the goal, its action the greedy push of the goal's
    source ball; its "task language" is the one-hot of the first goal the change made hold, when ``language``."""

    def __init__(self, language: bool = False):
        self.env = envs.make("clevr", physics="c")
        self.code_size = clevr_tasks.NUM_GOALS
        self.continuous_codes = False
        self.generator_params = {} if language else None

    def act(self, obs, code, rng, deterministic=False):
        goal = jnp.argmax(code)
        ball_xy = obs.reshape(clevr_tasks.NUM_BALLS, 2)
        source = jnp.asarray(clevr_tasks.GOAL_SOURCE)[goal]
        destination = jnp.asarray(clevr_tasks.GOAL_DESTINATION)[goal]
        relation = jnp.asarray(clevr_tasks.GOAL_RELATION)[goal]
        offset = clevr_tasks.TARGET_OFFSET * jnp.asarray(clevr_tasks.RELATION_VECTORS)[relation]
        towards = ball_xy[destination] + offset - ball_xy[source]
        unit = clevr_tasks.PUSH_DIRECTIONS / np.linalg.norm(clevr_tasks.PUSH_DIRECTIONS, axis=-1, keepdims=True)
        return (source * clevr_tasks.NUM_DIRECTIONS + jnp.argmax(jnp.asarray(unit) @ towards)).astype(jnp.int32)

    def task_language(self, start, now):
        shape = (clevr_tasks.NUM_BALLS, 2)
        newly = clevr_tasks.all_goals_success(now.reshape(shape)) & ~clevr_tasks.all_goals_success(start.reshape(shape))
        return jax.nn.one_hot(jnp.argmax(newly), clevr_tasks.NUM_GOALS) * jnp.any(newly)


def reference_chain(agent, key, goals, budget, advance_on="env"):
    """A chain step by step in plain Python (the semantics ``run_chains`` compiles): per clause, the step at which
    the chain moved on, and the first steps at which the env's test and the language's test held."""
    env, step, retarget = agent.env, jax.jit(agent.env.step), jax.jit(agent.env.retarget)
    state = env.reset(jax.random.split(key)[0], int(goals[0]))
    never = [-1] * len(goals)
    reached, by_env, by_language, total = list(never), list(never), list(never), 0
    for clause, goal in enumerate(goals):
        if clause:
            state = retarget(state, jnp.int32(goal))
        code, start = jax.nn.one_hot(goal, agent.code_size), state.obs
        for _ in range(budget):
            state, total = step(state, agent.act(state.obs, code, None)), total + 1
            holds = {"env": float(state.metrics["success"]) > 0.5, "language": False}
            if agent.generator_params is not None:
                holds["language"] = bool(jnp.all(jnp.abs(agent.task_language(start, state.obs) - code) < 0.5))
            if holds["env"] and by_env[clause] < 0:
                by_env[clause] = total
            if holds["language"] and by_language[clause] < 0:
                by_language[clause] = total
            if holds[advance_on]:
                reached[clause] = total
                break
        else:
            break
    return reached, by_env, by_language


@pytest.mark.parametrize(("language", "advance_on"), [(False, "env"), (True, "env"), (True, "language")])
def test_run_chains_is_the_plain_loop_of_clauses_without_reset(language, advance_on):
    agent = ScriptedClevrAgent(language)
    goals = np.array([[3, 50, 21], [70, 12, 44], [0, 33, 66], [15, 16, 17]])
    codes = np.eye(agent.code_size, dtype=np.float32)[goals]
    rng = jax.random.key(2)
    result = run_chains(agent, codes, goals, rng, advance_on, budget=12)
    keys = jax.random.split(rng, len(goals))
    expected = [reference_chain(agent, keys[i], goals[i], 12, advance_on) for i in range(len(goals))]
    np.testing.assert_array_equal(result.reached_step, [e[0] for e in expected])
    np.testing.assert_array_equal(result.env_step, [e[1] for e in expected])
    np.testing.assert_array_equal(result.language_step, [e[2] for e in expected])
    assert result.success_at[0] > 0  # the scripted pusher completes clauses, so the comparison has substance
    assert result.language_available == language and (result.agreement() is None) != language
    if language:
        assert (result.language_step >= 0).any()


def test_one_chain_episode_is_its_row_of_run_chains_with_the_physics_kept():
    agent = ScriptedClevrAgent()
    goals = np.array([[3, 50, 21], [70, 12, 44]])
    codes = np.eye(agent.code_size, dtype=np.float32)[goals]
    rng = jax.random.key(2)
    batch = run_chains(agent, codes, goals, rng, budget=12)
    for row, key in enumerate(jax.random.split(rng, len(goals))):
        episode = chain_episode(agent, codes[row], goals[row], key, budget=12)
        np.testing.assert_array_equal(episode.result.reached_step[0], batch.reached_step[row])
        assert episode.qpos.shape == (3 * 12 + 1, agent.env.mj_model.nq) and episode.clause.shape == (3 * 12,)
        steps = episode.length
        assert episode.valid[:steps].all() and not episode.valid[steps:].any()
        reached = episode.result.reached_step[0]
        assert steps == (reached.max() if (reached >= 0).all() else max(reached.max(), 0) + 12)
        # the clause followed moves on right after each reached step
        for clause, at in enumerate(reached[reached >= 0][:-1]):
            assert episode.clause[at - 1] == clause and episode.clause[at] == clause + 1
        np.testing.assert_array_equal(episode.qpos[steps + 1 :], np.repeat(episode.qpos[steps][None], 36 - steps, 0))
        start = agent.env.reset(jax.random.split(key)[0], int(goals[row, 0]))
        np.testing.assert_allclose(episode.qpos[0], start.data.qpos, atol=1e-6)  # jit and eager round apart


def test_run_chains_refuses_what_it_cannot_run():
    agent = ScriptedClevrAgent()
    goals = np.array([[3, 50], [70, 12]])
    codes = np.eye(agent.code_size, dtype=np.float32)[goals]
    with pytest.raises(ValueError, match="TL generator"):
        run_chains(agent, codes, goals, jax.random.key(0), "language")
    with pytest.raises(ValueError, match="agree"):
        run_chains(agent, codes[:, :1], goals, jax.random.key(0))
    with pytest.raises(ValueError, match="goals must lie"):
        run_chains(agent, codes, goals + 40, jax.random.key(0))


# --- the shipped agents --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def kitchen_agent():
    return load("kitchen")


def test_the_shipped_kitchen_generator_names_each_scripted_sub_task_as_the_translator_does(kitchen_agent):
    """The shipped generator is the one the shipped translator learnt from: its code of a scripted episode's change
    (reset state -> the state where the sub-task first held) is the code the translator gives the sub-task's
    training instructions."""
    env = kitchen_agent.env

    def episode(key, goal):
        start = env.reset(key, goal)

        def step(carry, i):
            state, final = carry
            stepped = env.step(state, scripted_action(state.obs, goal, i))
            first = (stepped.metrics["success"] > 0.5) & jnp.isnan(final[0])
            return (stepped, jnp.where(first, stepped.obs, final)), None

        (_, final), _ = jax.lax.scan(step, (start, jnp.full_like(start.obs, jnp.nan)), jnp.arange(env.episode_length))
        return start.obs, final

    goals = jnp.arange(env.num_goals)
    starts, finals = jax.jit(jax.vmap(episode))(jax.random.split(jax.random.key(0), env.num_goals), goals)
    assert not np.isnan(np.asarray(finals)).any()
    codes = np.asarray(jax.vmap(kitchen_agent.task_language)(starts, finals))
    for goal in range(env.num_goals):
        np.testing.assert_array_equal(codes[goal], kitchen_agent.goal_code(goal))


def test_the_shipped_clevr_agent_has_no_generator_and_runs_chains():
    agent = load("clevr")
    assert agent.generator_params is None
    goals = np.array([[1, 2], [40, 8]])
    codes = np.stack([[agent.goal_code(g) for g in row] for row in goals])
    result = run_chains(agent, codes, goals, jax.random.key(0), budget=5)
    assert not result.language_available and result.budget == 5
    steps = result.reached_step
    assert ((steps == -1) | ((steps >= 1) & (steps <= 10))).all()


# --- the command ---------------------------------------------------------------------------------------------
def test_chains_command_writes_the_calvin_numbers(tmp_path, capsys, kitchen_agent):
    out = tmp_path / "chains.json"
    argv = ["kitchen", "--chains", "3", "--length", "2", "--all-chains", "2", "--budget", "20", "--json", str(out)]
    assert chains_command.main(argv) == 0
    record = json.loads(out.read_text())
    assert record["length"] == 2 and record["chains"] == 3 and len(record["success_at"]) == 2
    assert record["average_length"] == pytest.approx(sum(record["success_at"]))
    language = record["seeds"]["0"]["language"]
    assert language is not None and 0 <= language["agreement"]["reached"] <= 1
    assert len(record["all_goals"]["0"]["success_at"]) == 6
    printed = capsys.readouterr().out
    assert "| 0 | env |" in printed and "task language" in printed


def test_chain_phrasings_are_held_out_test_sentences(kitchen_agent):
    phrasings = chains_command.test_phrasings(kitchen_agent)
    cache = kitchen_agent.cache
    train = {s for s, t in zip(cache.sentences, cache.is_train, strict=True) if t}
    assert sorted(phrasings) == list(range(6))
    assert all(sentence not in train for sentences in phrasings.values() for sentence in sentences)
    goals, sentences = chains_command.sample_chains(phrasings, 20, 4, np.random.default_rng(0))
    assert all(len(set(row)) == 4 for row in goals.tolist())
    assert all(s in phrasings[int(g)] for row, words in zip(goals, sentences, strict=True) for g, s in zip(row, words))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["kitchen", "--chains", "0"], "--chains must be >= 1"),
        (["kitchen", "--length", "0"], "--length must be >= 1"),
        (["kitchen", "--budget", "0"], "--budget must be >= 1"),
        (["no-such-agent"], "does not exist"),
    ],
)
def test_chains_command_bad_input_is_one_line(capsys, argv, message):
    assert message in one_line_error(capsys, chains_command.main, argv)


def test_a_run_and_the_agent_shipped_from_it_share_the_seeds_generator(clevr_run, tmp_path):
    from experiments import ship
    from experiments.reports import load_agent

    out, _ = clevr_run
    run_agent = load_agent(out, seed=1)  # the run's own generator: seed-stacked in talar/task_language
    assert run_agent.generator_params is not None
    shipped = load(ship.ship(ship.ShipArgs(out, name="probe", seed=1, out=tmp_path)))
    assert_trees_equal(shipped.generator_params, run_agent.generator_params)
    other = load_agent(out, seed=0).generator_params
    assert not all(
        np.array_equal(a, b) for a, b in zip(jax.tree.leaves(other), jax.tree.leaves(shipped.generator_params))
    )
    states = np.random.default_rng(0).uniform(-0.4, 0.5, (8, 10)).astype(np.float32)
    np.testing.assert_array_equal(
        shipped.task_language(states, states[::-1]), run_agent.task_language(states, states[::-1])
    )
