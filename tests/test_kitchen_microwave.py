"""The kitchen's microwave reward: the posture term's target grasps the closed door's handle, and its stillness test
is not switched off by observation noise (results/kitchen-seeds/: with the at-success target and the noisy test,
3 of 8 probe seeds opened the microwave; with both fixes 8 of 8)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.kitchen import tasks
from envs.kitchen.scripted import scripted_action

MICROWAVE = tasks.task_id("microwave")


def _fingertips_to_handle(posture: np.ndarray) -> float:
    """Metres from the fingertips' midpoint to the microwave handle, the arm at ``posture``, the door closed."""
    env = envs.make("kitchen", physics="c", noise_ratio=0.0)
    model, data = env.mj_model, mujoco.MjData(env.mj_model)
    qpos_index, obs_index = env.observation_map
    obs = tasks.INIT_OBS.copy()
    obs[: tasks.NUM_ROBOT_JOINTS] = posture
    data.qpos[:] = env.init_qpos
    data.qpos[qpos_index] = obs[obs_index]
    mujoco.mj_kinematics(model, data)
    fingertips = (data.geom("left_finger").xpos + data.geom("right_finger").xpos) / 2
    return float(np.linalg.norm(fingertips - data.geom("micro_handle").xpos))


def test_microwave_target_holds_the_fingers_at_the_closed_doors_handle():
    """The at-success target ('scripted') leaves the fingertips 0.28 m from the closed door's handle, where parking
    costs almost nothing and opens nothing; the 'grasp' target puts them at the handle."""
    assert _fingertips_to_handle(tasks.posture_targets("scripted")[MICROWAVE]) > 0.25
    assert _fingertips_to_handle(tasks.posture_targets("grasp")[MICROWAVE]) < 0.12
    # the other sub-tasks keep the scripted controller's posture at success
    others = [goal for goal in range(tasks.NUM_TASKS) if goal != MICROWAVE]
    np.testing.assert_array_equal(tasks.posture_targets("grasp")[others], tasks.posture_targets("scripted")[others])


def test_grasp_target_is_the_scripted_controllers_posture_before_the_door_moves():
    """Re-derives the grasp target: the scripted controller's noise-free microwave episode at step 100, the last
    step before the door first moves."""
    env = envs.make("kitchen", physics="c", posture_targets="grasp", noise_ratio=0.0)
    step, act = jax.jit(env.step), jax.jit(scripted_action)
    state = env.reset(jax.random.PRNGKey(0), goal="microwave")
    doors = []
    for t in range(101):
        doors.append(float(state.obs[22]))
        if t < 100:
            state = step(state, act(state.obs, jnp.int32(MICROWAVE), jnp.int32(t)))
    np.testing.assert_allclose(state.obs[: tasks.NUM_ROBOT_JOINTS], tasks.MICROWAVE_GRASP_POSTURE, atol=2e-3)
    assert max(abs(door) for door in doors) < 0.02  # barely moved, of the 0.45 rad it must open


def _posture_term_share(stillness: str, steps: int = 40) -> float:
    """Share of the steps, the arm held still from the reset with observation noise on, on which the microwave's
    posture term applies (reward minus progress minus success is negative)."""
    env = envs.make("kitchen", physics="c", posture_targets="grasp", stillness=stillness)
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(0), goal="microwave")
    applied = 0
    for _ in range(steps):
        before = state.task.distance[MICROWAVE]
        state = step(state, jnp.zeros(9))
        posture = state.reward - (before - state.task.distance[MICROWAVE]) - state.metrics["success"]
        applied += float(posture) < -1e-6
    return applied / steps


def test_noise_free_stillness_test_keeps_the_posture_term_on():
    """The door's observation noise (+-0.01 rad, ten times the test's threshold) switches TALAR's noisy stillness
    test off on most steps although nothing moves; the noise-free test keeps the term on every still step."""
    assert _posture_term_share("true") == 1.0
    assert _posture_term_share("observed") < 0.5


def test_unknown_stillness_is_one_clear_error():
    with pytest.raises(ValueError, match="unknown stillness 'noisy'; choose one of observed, true"):
        envs.make("kitchen", physics="c", stillness="noisy")


def test_experiment_recipe_uses_the_fixed_microwave_reward():
    from experiments.recipes import get_recipe

    assert get_recipe("kitchen").env_options == {"posture_targets": "grasp", "stillness": "true"}


def _microwave_only_env(env_options: dict):
    """The kitchen with every episode's sub-task the microwave (the PPO test below learns that one alone)."""
    from envs.kitchen.env import KitchenConfig, KitchenEnv

    class MicrowaveKitchen(KitchenEnv):
        def reset(self, rng, goal=None):
            return super().reset(rng, goal=MICROWAVE)

    return MicrowaveKitchen(KitchenConfig(**env_options), "c")


@pytest.mark.slow
def test_goal_given_ppo_opens_the_microwave_within_a_small_budget():
    """The experiment's PPO, told the goal, on the microwave alone: with the old reward (the at-success target and
    the noisy stillness test) seeds 0 and 1 of base seed 0 stayed at 0 % at 0.41M steps; with the experiment's
    reward both open it."""
    import dataclasses

    from experiments.recipes import get_recipe
    from talar_jax.conditioning import GoalOneHotConditioner
    from talar_jax.ppo import run_ppo

    recipe = get_recipe("kitchen")
    env = _microwave_only_env(recipe.env_options)
    config = dataclasses.replace(
        recipe.ifp, num_seeds=2, total_env_steps=409_600, eval_every_chunks=100, eval_episodes=32
    )
    result = run_ppo(config, env, GoalOneHotConditioner(env.num_goals), None, progress=False, eval_splits=("train",))
    assert min(result.last_eval["train"]["success_per_seed"]) > 0.5, result.last_eval["train"]
