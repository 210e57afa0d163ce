"""The original envs' stepping style, per env name: one env, a Python loop of ``mj_step`` substeps per action.

Used by ``benchmarks.env_sps`` as the baseline the JAX backends are compared against. Each entry returns
env steps per second (steady state) of a random-action loop with episode resets.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import mujoco
import numpy as np

from envs.clevr import tasks as clevr_tasks
from envs.clevr.reference import ORIGINAL_XML as CLEVR_ORIGINAL_XML


def clevr_original_steps_per_second(num_steps: int, seed: int = 0, episode_length: int = 50) -> float:
    """CLEVR-Robot as google-research/clevr_robot_env + TALAR step it, on the original free-ball model.

    Per action: dm_control's ``reset_context`` (``mj_resetData``, write qpos/qvel with the pusher teleported 0.15 d
    behind the ball, ``mj_forward``), 40 ``mj_step`` substeps of 0.01 s at force d, then observation, reward and
    success in numpy. Resets sample a scene with the original's per-ball rejection sampling. Not counted (so the
    baseline is, if anything, favoured): the original regenerates and recompiles the scene XML at every reset.
    """
    model = mujoco.MjModel.from_xml_path(str(CLEVR_ORIGINAL_XML))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    ball_at = np.arange(clevr_tasks.NUM_BALLS) * 7

    def reset() -> tuple[np.ndarray, int, float]:
        placed: list[np.ndarray] = []
        while len(placed) < clevr_tasks.NUM_BALLS:  # the original: 10 tries per ball, else restart the scene
            for _ in range(10):
                candidate = rng.uniform(clevr_tasks.REGION_LOW, clevr_tasks.REGION_HIGH)
                if all(np.linalg.norm(candidate - other) >= clevr_tasks.MIN_SEPARATION for other in placed):
                    placed.append(candidate)
                    break
            else:
                placed = []
        mujoco.mj_resetData(model, data)
        for ball, (x, y) in zip(ball_at, placed, strict=True):
            data.qpos[ball : ball + 7] = x, y, -0.195, 1.0, 0.0, 0.0, 0.0
        mujoco.mj_forward(model, data)
        goal = int(rng.integers(clevr_tasks.NUM_GOALS))
        return np.array(placed), goal, _clevr_distance(np.array(placed), goal)

    ball_xy, goal, distance = reset()
    steps_in_episode = 0
    start = time.perf_counter()
    for _ in range(num_steps):
        action = int(rng.integers(clevr_tasks.NUM_ACTIONS))
        force = clevr_tasks.PUSH_DIRECTIONS[action % clevr_tasks.NUM_DIRECTIONS].astype(np.float64)
        qpos, qvel = data.qpos.copy(), data.qvel.copy()
        mujoco.mj_resetData(model, data)  # dm_control's reset_context
        qpos[-2:] = ball_xy[action // clevr_tasks.NUM_DIRECTIONS] - clevr_tasks.PUSH_OFFSET * force
        qvel[-2:] = 0.0
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(model, data)
        data.ctrl[:] = force
        for _ in range(40):
            mujoco.mj_step(model, data)
        ball_xy = np.stack([data.qpos[ball_at], data.qpos[ball_at + 1]], axis=1)
        new_distance = _clevr_distance(ball_xy, goal)
        success = _clevr_success(ball_xy, goal)
        _reward = 100.0 if success else 10.0 * (distance - new_distance)
        distance = new_distance
        steps_in_episode += 1
        if success or steps_in_episode >= episode_length:
            ball_xy, goal, distance = reset()
            steps_in_episode = 0
    return num_steps / (time.perf_counter() - start)


def _clevr_distance(ball_xy: np.ndarray, goal: int) -> float:
    source, destination = clevr_tasks.GOAL_SOURCE[goal], clevr_tasks.GOAL_DESTINATION[goal]
    unit = clevr_tasks.RELATION_VECTORS[clevr_tasks.GOAL_RELATION[goal]]
    return float(np.linalg.norm(ball_xy[source] - ball_xy[destination] - clevr_tasks.TARGET_OFFSET * unit))


def _clevr_success(ball_xy: np.ndarray, goal: int) -> bool:
    offset = ball_xy[clevr_tasks.GOAL_SOURCE[goal]] - ball_xy[clevr_tasks.GOAL_DESTINATION[goal]]
    offset = np.where(np.abs(offset) < 1e-3, 0.0, offset)
    angle = np.degrees(np.arctan2(offset[1], offset[0])) % 360.0
    relation = (0, 2, 1, 3)[int(((angle - 45.0) % 360.0) // 90.0)]
    return relation == clevr_tasks.GOAL_RELATION[goal] and np.linalg.norm(offset) < clevr_tasks.SUCCESS_DISTANCE


def kitchen_original_steps_per_second(num_steps: int, seed: int = 0, episode_length: int = 280) -> float:
    """FrankaKitchen as D4RL / TALAR step it, on our kitchen model with the original physics settings.

    Per action: ``q_des = clip(q_obs_prev + 2 a 0.08, pos_bound)`` into the position servos, 40 ``mj_step`` substeps
    of 0.002 s (Euler, Newton 100 iterations / 50 line-search), then the noisy 30-D observation (ratio 0.1), the
    TALAR ``prev_curr`` reward with the posture term and the success test in numpy. Resets restore the fixed
    initial state and draw one of the six sub-tasks. Same lean model as ``envs.make("kitchen")`` (the
    gymnasium-robotics FrankaKitchen-v1 with its mesh model ran at ~327 env steps/s on this kind of machine).
    """
    from envs.kitchen import KitchenEnv
    from envs.kitchen import env as kitchen_env
    from envs.kitchen import tasks as kitchen_tasks

    env = KitchenEnv(physics="c")  # for the model file and the qpos <-> observation map only
    model = mujoco.MjModel.from_xml_path(str(env.xml_path))
    model.opt.timestep, model.opt.integrator = 0.002, mujoco.mjtIntegrator.mjINT_EULER
    model.opt.iterations, model.opt.ls_iterations = 100, 50
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    qpos_index, obs_index = env.observation_map
    amplitude = 0.1 * kitchen_tasks.NOISE_AMPLITUDE

    def observe() -> np.ndarray:
        obs = kitchen_tasks.INIT_OBS.astype(np.float64)
        obs[obs_index] = data.qpos[qpos_index]
        obs[[10, 12, 14, 16]] = np.clip(obs[[9, 11, 13, 15]] / kitchen_env.KNOB_PER_BURNER, -0.009, 0.0)
        obs[18] = np.clip(obs[17] / kitchen_env.SWITCH_PER_LAMP, -0.05, 0.0)
        return obs + amplitude * rng.uniform(-1.0, 1.0, obs.shape)

    def distance(obs: np.ndarray, goal: int) -> float:
        return float(np.linalg.norm(kitchen_tasks.TASK_MASK[goal] * (obs - kitchen_tasks.TASK_GOAL[goal])))

    def reset() -> tuple[np.ndarray, int, float]:
        mujoco.mj_resetData(model, data)
        data.qpos[:] = env.init_qpos
        mujoco.mj_forward(model, data)
        obs = observe()
        goal = int(rng.integers(kitchen_tasks.NUM_TASKS))
        return obs, goal, distance(obs, goal)

    obs, goal, previous = reset()
    steps_in_episode = 0
    start = time.perf_counter()
    for _ in range(num_steps):
        action = rng.uniform(-1.0, 1.0, 9)
        data.ctrl[:] = np.clip(obs[:9] + 2.0 * action * 0.08, kitchen_env.POS_LOW, kitchen_env.POS_HIGH)
        for _ in range(40):
            mujoco.mj_step(model, data)
        obs = observe()
        current = distance(obs, goal)
        success = current < kitchen_tasks.BONUS_THRESH
        _reward = previous - current + float(success)
        if abs(previous - current) <= kitchen_tasks.STILL_THRESH:
            _reward -= 0.01 * float(np.linalg.norm(obs[:9] - kitchen_tasks.TARGET_POSTURE[goal]))
        previous = current
        steps_in_episode += 1
        if success or steps_in_episode >= episode_length:
            obs, goal, previous = reset()
            steps_in_episode = 0
    return num_steps / (time.perf_counter() - start)


# env name -> f(num_steps, seed) -> env steps per second; other envs add their original loop here.
ORIGINAL_STYLE: dict[str, Callable[..., float]] = {
    "clevr": clevr_original_steps_per_second,
    "kitchen": kitchen_original_steps_per_second,
}
