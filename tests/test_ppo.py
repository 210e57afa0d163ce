"""PPO on a tiny goal-conditioned point env: learning (discrete and continuous), seeds, determinism, resume, dataset."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from talar_jax.conditioning import GoalOneHotConditioner, InstructionSampler, InstructionTableConditioner
from talar_jax.dataset import TaskDataset, collect_task_dataset, policy_behaviour
from talar_jax.logging import ListLogger
from talar_jax.networks import init_observation_stats, make_ppo_networks, update_observation_stats
from talar_jax.ppo import PPOConfig, derive, make_train, run_ppo
from tests.point_env import GOALS, SUCCESS_RADIUS, PointConfig, PointEnv

CONFIG = PPOConfig(
    num_envs=16,
    rollout_length=32,
    total_env_steps=25_600,
    updates_per_chunk=10,
    num_seeds=2,
    eval_episodes=64,
    ent_coef=0.0,
)  # 5 chunks of 5120 steps
TIMING_KEYS = ("eval/seconds", "train/sps", "train/chunk_s", "train/wall_s", "train/compile_s")


def _comparable(row):
    return {key: value for key, value in row.items() if key not in TIMING_KEYS}


class _KillAfter(ListLogger):
    """Raises (like a kill) after ``chunks`` chunks were logged; the checkpoint of the last one is on disk."""

    def __init__(self, chunks):
        super().__init__()
        self.chunks = chunks

    def write(self, step, metrics):
        super().write(step, metrics)
        if step >= self.chunks:
            raise KeyboardInterrupt


@pytest.fixture(scope="module")
def discrete_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ppo") / "full"
    return run_ppo(CONFIG, PointEnv(), GoalOneHotConditioner(4), out, progress=False, target_success=0.8), out


def test_derive():
    sizes = derive(CONFIG)
    assert (sizes.env_steps_per_update, sizes.num_minibatches) == (512, 4)
    assert (sizes.num_chunks, sizes.total_env_steps) == (5, 25_600)
    with pytest.raises(ValueError, match="multiple of minibatch_size"):
        PPOConfig(num_envs=3, rollout_length=5, minibatch_size=4)
    with pytest.raises(ValueError, match="num_epochs must be >= 1"):
        dataclasses.replace(CONFIG, num_epochs=0)


def test_discrete_learns_and_seeds_are_vmapped(discrete_run):
    result, out = discrete_run
    assert len(result.history) == 5 and result.env_steps == 25_600
    per_seed = result.last_eval["train"]["success_per_seed"]
    assert len(per_seed) == 2 and min(per_seed) >= 0.8, per_seed
    assert result.last_eval["test"]["success"] >= 0.8
    assert result.target_reached is not None and result.target_reached["env_steps"] <= 25_600
    assert result.history[0]["eval/train/success"] < result.history[-1]["eval/train/success"]
    leaves = jax.tree.leaves(result.params)
    assert all(leaf.shape[0] == 2 for leaf in leaves)
    assert any(not np.allclose(leaf[0], leaf[1]) for leaf in leaves)  # two seeds, two different runs
    assert (out / "config.json").exists() and (out / "metrics.jsonl").read_text().count("\n") == 5


def test_same_seed_same_metrics_and_resume(discrete_run, tmp_path):
    result, _ = discrete_run
    killed = _KillAfter(2)
    with pytest.raises(KeyboardInterrupt):
        run_ppo(CONFIG, PointEnv(), GoalOneHotConditioner(4), tmp_path, progress=False, logger=killed)
    # Determinism: the first two chunks of a fresh run with the same seed match the uninterrupted run.
    for (_, row), reference in zip(killed.records, result.history[:2], strict=True):
        assert _comparable(row) == _comparable(reference)
    resumed = run_ppo(CONFIG, PointEnv(), GoalOneHotConditioner(4), tmp_path, progress=False)
    assert [row["train/env_steps"] for row in resumed.history] == [15_360, 20_480, 25_600]
    for row, reference in zip(resumed.history, result.history[2:], strict=True):
        assert _comparable(row) == _comparable(reference)
    jax.tree.map(np.testing.assert_array_equal, resumed.params, result.params)
    with pytest.raises(ValueError, match="different config"):
        run_ppo(dataclasses.replace(CONFIG, learning_rate=1e-3), PointEnv(), GoalOneHotConditioner(4), tmp_path)


def test_stop_at_target_and_resume_after_it(tmp_path):
    """A run stops after the first evaluation reaching the target; resuming its folder trains nothing more, keeps
    the recorded target and evaluates the stopped parameters afresh."""
    config = dataclasses.replace(CONFIG, num_seeds=1, eval_episodes=8, final_eval_episodes=16)
    point = PointEnv(), GoalOneHotConditioner(4)
    stopped = run_ppo(config, *point, tmp_path, progress=False, target_success=0.0, stop_at_target=True)
    assert [row["train/env_steps"] for row in stopped.history] == [5_120]
    assert stopped.target_reached["env_steps"] == 5_120
    assert stopped.target_reached["success"] == stopped.last_eval["train"]["success"]
    resumed = run_ppo(config, *point, tmp_path, progress=False, target_success=0.0, stop_at_target=True)
    assert resumed.history == [] and resumed.target_reached == stopped.target_reached
    assert resumed.wall_s == stopped.wall_s and resumed.env_steps == 5_120
    assert len(resumed.last_eval["train"]["success_per_goal"]) == 4
    jax.tree.map(np.testing.assert_array_equal, resumed.params, stopped.params)


def test_continuous_learns_with_trainable_conditioner():
    # Instructions 0..7: goal g has train instructions {2g, 2g+1}; the table rows start as noisy one-hots and train.
    table = np.repeat(np.eye(4, dtype=np.float32), 2, axis=0) + 0.1
    lookup = np.arange(8, dtype=np.int32).reshape(4, 2)
    conditioner = InstructionTableConditioner(table, {"train": (lookup, [2, 2, 2, 2])}, trainable=True)
    config = dataclasses.replace(CONFIG, num_seeds=1, total_env_steps=20_480)
    result = run_ppo(
        config, PointEnv(PointConfig(continuous=True)), conditioner, None, progress=False, eval_splits=("train",)
    )
    assert result.last_eval["train"]["success"] >= 0.8, result.last_eval["train"]
    assert not np.allclose(result.params["conditioner"]["table"][0], table)  # optimised jointly with the policy


def test_observation_normalisation_statistics_and_learning():
    rng = np.random.default_rng(0)
    first, second = rng.normal(2.0, 3.0, (50, 3)), rng.normal(-1.0, 0.5, (70, 3))
    stats = update_observation_stats(update_observation_stats(init_observation_stats(3), first), second)
    both = np.concatenate([first, second])
    np.testing.assert_allclose(stats["mean"], both.mean(0), rtol=1e-4)
    np.testing.assert_allclose(stats["var"], both.var(0), rtol=1e-3)
    config = dataclasses.replace(CONFIG, num_seeds=1, total_env_steps=20_480, normalize_observations=True)
    env = PointEnv(PointConfig(continuous=True))
    result = run_ppo(config, env, GoalOneHotConditioner(4), None, progress=False, eval_splits=("train",))
    assert result.last_eval["train"]["success"] >= 0.8, result.last_eval["train"]
    learned = jax.tree.map(lambda leaf: leaf[0], result.params["obs_normalizer"])
    # statistics of every observation acted on, untouched by the optimiser (Adam would move count and var too)
    np.testing.assert_allclose(learned["count"], 20_480, rtol=1e-6)
    assert np.all(np.asarray(learned["var"]) > 0.01) and np.all(np.abs(np.asarray(learned["mean"])) < 2.0)


def test_collect_task_dataset(discrete_run, tmp_path):
    result, _ = discrete_run
    params = jax.tree.map(lambda leaf: leaf[0], result.params)
    # Language: goal g has training instructions {10g, 10g+1}; goal 3 has none, so its episodes are skipped.
    sampler = InstructionSampler({"train": ([[0, 1], [10, 11], [20, 21], [-1, -1]], [2, 2, 2, 0])})
    networks = make_ppo_networks(2, 4, PointEnv().action_spec)
    behaviour = policy_behaviour(networks, params, GoalOneHotConditioner(4))
    dataset = collect_task_dataset(
        PointEnv(),
        behaviour,
        300,
        jax.random.PRNGKey(3),
        sampler,
        num_envs=32,
        config={"env": "point"},
    )
    assert len(dataset) == 300 and dataset.states.shape == (300, 2) and dataset.actions.shape == (300,)
    assert set(np.unique(dataset.goal_ids)) <= {0, 1, 2}
    np.testing.assert_array_equal(dataset.instruction_ids // 10, dataset.goal_ids)
    distance = np.linalg.norm(dataset.final_states - GOALS[dataset.goal_ids], axis=1)
    assert np.all(distance < SUCCESS_RADIUS)  # s_T of every tuple shows its goal achieved
    assert dataset.config["collection"]["goals_without_train_instructions"] == [3]
    dataset.save(tmp_path)
    loaded = TaskDataset.load(tmp_path)
    np.testing.assert_array_equal(loaded.states, dataset.states)
    assert loaded.config["env"] == "point"


@pytest.mark.slow
def test_whole_run_in_one_program():
    config = dataclasses.replace(CONFIG, total_env_steps=10_240)
    learner = make_train(config, PointEnv(), GoalOneHotConditioner(4))
    state, metrics = jax.jit(jax.vmap(learner.train))(jax.random.split(jax.random.PRNGKey(0), 2))
    assert metrics["losses/value"].shape == (2, 2, 10)
    assert int(state.env_steps[0]) == 10_240


@pytest.mark.slow
def test_oracle_command_quick(tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "oracle"
    command = [
        sys.executable,
        "-m",
        "experiments.oracle",
        "--env",
        "clevr",
        "--out",
        str(out),
        "--quick",
        "--no-progress",
        "--num-tuples",
        "200",
        "--collector",
        "policy",
    ]
    subprocess.run(command, check=True, timeout=600, capture_output=True)
    summary = json.loads((out / "oracle.json").read_text())
    assert summary["collector"] == "policy" and len(summary["eval"]["train"]["success_per_goal"]) == 80
    dataset = TaskDataset.load(out / "dataset")
    assert len(dataset) == 200 and dataset.states.shape == (200, 10)


def test_scripted_clevr_collector_pushes_only_the_source_ball(tmp_path):
    from envs.clevr import tasks
    from experiments.oracle import OracleArgs, run
    from experiments.recipes import get_recipe

    args = OracleArgs(env="clevr", out=tmp_path / "oracle", num_tuples=600, collect_envs=64, progress=False)
    success = run(args)
    assert 0.5 < success < 1.0  # greedy pushes of the source alone cannot reach goals beyond a wall
    dataset = TaskDataset.load(args.out / "dataset")
    assert len(dataset) == 600 and dataset.config["collector"] == "scripted"
    # stored actions are 40-way push ids of the goal's source ball
    np.testing.assert_array_equal(dataset.actions // tasks.NUM_DIRECTIONS, tasks.GOAL_SOURCE[dataset.goal_ids])
    # every kept episode ends in a state satisfying its goal (kept = successful only)
    final = jnp.asarray(dataset.final_states.reshape(-1, 5, 2))
    assert bool(jnp.all(jax.vmap(tasks.goal_success)(final, jnp.asarray(dataset.goal_ids))))
    with pytest.raises(ValueError, match="unknown collector"):
        run(OracleArgs(env="clevr", out=tmp_path / "c", collector="magic"))
    with pytest.raises(ValueError, match="unknown experiment env 'kitchen-all'; valid: clevr, kitchen"):
        get_recipe("kitchen-all")


def test_scripted_kitchen_collector_covers_all_six_subtasks(tmp_path):
    from envs.kitchen import tasks
    from experiments.oracle import OracleArgs, run

    args = OracleArgs(env="kitchen", out=tmp_path / "oracle", num_tuples=4000, collect_envs=64, progress=False)
    assert run(args) > 0.8  # the noisy scripted controller still solves most episodes
    dataset = TaskDataset.load(args.out / "dataset")
    assert len(dataset) == 4000 and dataset.config["collector"] == "scripted"
    assert set(np.unique(dataset.goal_ids)) == set(range(tasks.NUM_TASKS))  # microwave included
    distance = jax.vmap(tasks.task_distances)(jnp.asarray(dataset.final_states))
    final_distance = np.asarray(distance)[np.arange(len(dataset)), dataset.goal_ids]
    assert np.all(final_distance < tasks.BONUS_THRESH)  # kept episodes end with their sub-task solved


def test_evaluation_schedule_leaves_training_bit_identical(discrete_run):
    """Evaluation draws its own keys: a run evaluated rarely, on other episode counts, with a dense final
    evaluation, trains exactly the same parameters as one evaluated after every chunk."""
    result, _ = discrete_run
    sparse = dataclasses.replace(CONFIG, eval_every_chunks=2, eval_episodes=8, final_eval_episodes=96)
    other = run_ppo(sparse, PointEnv(), GoalOneHotConditioner(4), None, progress=False)
    for a, b in zip(jax.tree.leaves(result.params), jax.tree.leaves(other.params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert [_comparable(r)["train/success"] for r in other.history] == [r["train/success"] for r in result.history]
    evaluated = ["eval/train/success" in row for row in other.history]
    assert evaluated == [False, True, False, True, True]  # every 2 chunks, and after the last
    per_seed_goal = other.last_eval["train"]["success_per_seed_goal"]
    assert len(per_seed_goal) == 2 and all(len(row) == 4 for row in per_seed_goal)
    # the final evaluation's 96 episodes per seed: success rates in steps of 1/96 over the whole split's seeds
    counts = np.array(other.last_eval["train"]["success_per_seed"]) * 96
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    with pytest.raises(ValueError, match="final_eval_episodes must be >= 0"):
        dataclasses.replace(CONFIG, final_eval_episodes=-1)


def test_evaluation_stops_when_every_episode_ended_with_the_same_records():
    """``evaluate_episodes`` ends its loop once every episode has ended; its records equal those of a loop over the
    whole time limit with the same per-step keys."""
    from talar_jax.acting import ConditionedEnv, evaluate_episodes

    env = ConditionedEnv(PointEnv(PointConfig(continuous=True)), GoalOneHotConditioner(4), "train")
    goals = jnp.asarray(GOALS)
    steps_taken = []

    def act(obs, instruction, rng):  # towards the goal, with noise: episodes end at different steps
        steps_taken.append(1)
        towards = goals[instruction] - obs[..., :2]  # the one-hot conditioner's instruction is the goal id
        return jnp.clip(8.0 * towards + 0.5 * jax.random.normal(rng, towards.shape), -1.0, 1.0)

    rng, num_episodes, limit = jax.random.PRNGKey(3), 32, int(env.env.episode_length)
    record = evaluate_episodes(env, act, rng, num_episodes)
    assert len(steps_taken) == 1  # traced once, inside the loop
    rng_reset, rng_act = jax.random.split(rng)
    carry = jax.vmap(env.reset)(jax.random.split(rng_reset, num_episodes))
    finished, success, length = np.zeros(num_episodes), np.zeros(num_episodes), np.zeros(num_episodes)
    for key in jax.random.split(rng_act, limit):
        carry, outcome = jax.vmap(env.step)(carry, act(carry.state.obs, carry.instruction, key))
        ends = (finished < 0.5) & (np.asarray(outcome["termination"] + outcome["truncation"]) > 0.5)
        length += finished < 0.5
        success = np.where(ends, outcome["success"], success)
        finished = np.where(ends, 1.0, finished)
    np.testing.assert_array_equal(record["success"], success)
    np.testing.assert_array_equal(record["episode_length"], length)
    assert success.mean() > 0 and length.max() < limit  # the loop stopped before the time limit


def test_programs_compile_with_the_fusion_emitters_unless_they_step_mjx():
    """The CPU flag MJX needs is overridden per program: a learner of a C-physics env (or a high-level env over one)
    compiles its chunk with XLA's fusion emitters; one of an MJX env, or of an env that does not name its physics,
    keeps the process flag. ``learn`` is the update's SGD: the chunk's parameters follow from it."""
    import envs
    from talar_jax.hrl import HighLevelEnv

    fusion = {"xla_cpu_use_fusion_emitters": True}
    cond = GoalOneHotConditioner(80)
    assert make_train(CONFIG, envs.make("clevr", physics="c"), cond).compiler_options == fusion
    assert make_train(CONFIG, envs.make("clevr", physics="mjx"), cond).compiler_options == {}
    assert make_train(CONFIG, PointEnv(), GoalOneHotConditioner(4)).compiler_options == {}
    spec = envs.make("clevr", physics="c").action_spec
    high = HighLevelEnv(envs.make("clevr", physics="c"), lambda obs, code, rng: jnp.zeros((), jnp.int32), spec, None)
    assert make_train(CONFIG, high, GoalOneHotConditioner(1)).compiler_options == fusion


def test_learn_is_the_updates_sgd():
    """``Learner.learn`` on a flat batch moves the parameters and returns per-epoch, per-minibatch loss metrics."""
    from talar_jax.ppo import Minibatch

    learner = make_train(CONFIG, PointEnv(), GoalOneHotConditioner(4))
    state = learner.init(jax.random.PRNGKey(0))
    size = derive(CONFIG).env_steps_per_update
    rng = np.random.default_rng(0)
    normal = [jnp.asarray(rng.normal(size=size), jnp.float32) for _ in range(3)]
    obs = jnp.asarray(rng.normal(size=(size, PointEnv().observation_size)), jnp.float32)
    action = jnp.asarray(rng.integers(0, PointEnv().action_spec.size, size), jnp.int32)
    batch = Minibatch(obs, jnp.zeros(size, jnp.int32), action, *normal)
    params, _, metrics = jax.jit(learner.learn)(state.params, state.opt_state, batch, jax.random.PRNGKey(1))
    moved = [not np.array_equal(a, b) for a, b in zip(jax.tree.leaves(state.params), jax.tree.leaves(params))]
    assert any(moved)
    assert metrics["losses/policy"].shape == (CONFIG.num_epochs, derive(CONFIG).num_minibatches)
