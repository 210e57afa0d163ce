"""The original envs' stepping style, per env name: one numpy env, a Python loop of ``mj_step`` substeps per action.

Each env has the Gymnasium API (``reset(seed=None) -> (obs, info)``, ``step(action) -> (obs, reward, terminated,
truncated, info)``) without depending on gymnasium. ``benchmarks.env_sps`` times a random-action loop of one env as
the baseline the JAX backends are compared against; ``benchmarks.train_sps`` lets stable-baselines3 drive them, as
the original pipeline did (observation = [obs, goal one-hot]).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from envs.clevr import tasks as clevr_tasks
from envs.clevr.env import ORIGINAL_XML as CLEVR_ORIGINAL_XML


class ClevrOriginalEnv:
    """CLEVR-Robot as google-research/clevr_robot_env + TALAR step it, on the original free-ball model.

    Per action: dm_control's ``reset_context`` (``mj_resetData``, write qpos/qvel with the pusher teleported 0.15 d
    behind the ball, ``mj_forward``), 40 ``mj_step`` substeps of 0.01 s at force d, then observation, reward and
    success in numpy. Resets sample a scene with the original's per-ball rejection sampling. Not counted (so the
    baseline is, if anything, favoured): the original regenerates and recompiles the scene XML at every reset.
    Observation: the 10-D ball positions; action: one of 40 pushes.
    """

    num_actions = clevr_tasks.NUM_ACTIONS
    observation_size = 2 * clevr_tasks.NUM_BALLS
    num_goals = clevr_tasks.NUM_GOALS

    def __init__(self, seed: int = 0, episode_length: int = 50):
        self.model = mujoco.MjModel.from_xml_path(str(CLEVR_ORIGINAL_XML))
        self.data = mujoco.MjData(self.model)
        self.rng = np.random.default_rng(seed)
        self.episode_length = episode_length
        self.ball_at = np.arange(clevr_tasks.NUM_BALLS) * 7

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        placed: list[np.ndarray] = []
        while len(placed) < clevr_tasks.NUM_BALLS:  # the original: 10 tries per ball, else restart the scene
            for _ in range(10):
                candidate = self.rng.uniform(clevr_tasks.REGION_LOW, clevr_tasks.REGION_HIGH)
                if all(np.linalg.norm(candidate - other) >= clevr_tasks.MIN_SEPARATION for other in placed):
                    placed.append(candidate)
                    break
            else:
                placed = []
        mujoco.mj_resetData(self.model, self.data)
        for ball, (x, y) in zip(self.ball_at, placed, strict=True):
            self.data.qpos[ball : ball + 7] = x, y, -0.195, 1.0, 0.0, 0.0, 0.0
        mujoco.mj_forward(self.model, self.data)
        self.ball_xy, self.steps = np.array(placed), 0
        self.goal = int(self.rng.integers(clevr_tasks.NUM_GOALS))
        self.distance = _clevr_distance(self.ball_xy, self.goal)
        return self.ball_xy.reshape(-1).astype(np.float32), {"goal": self.goal}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        model, data = self.model, self.data
        force = clevr_tasks.PUSH_DIRECTIONS[int(action) % clevr_tasks.NUM_DIRECTIONS].astype(np.float64)
        qpos, qvel = data.qpos.copy(), data.qvel.copy()
        mujoco.mj_resetData(model, data)  # dm_control's reset_context
        qpos[-2:] = self.ball_xy[int(action) // clevr_tasks.NUM_DIRECTIONS] - clevr_tasks.PUSH_OFFSET * force
        qvel[-2:] = 0.0
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(model, data)
        data.ctrl[:] = force
        for _ in range(40):
            mujoco.mj_step(model, data)
        self.ball_xy = np.stack([data.qpos[self.ball_at], data.qpos[self.ball_at + 1]], axis=1)
        new_distance = _clevr_distance(self.ball_xy, self.goal)
        success = _clevr_success(self.ball_xy, self.goal)
        reward = 100.0 if success else 10.0 * (self.distance - new_distance)
        self.distance, self.steps = new_distance, self.steps + 1
        truncated = not success and self.steps >= self.episode_length
        return self.ball_xy.reshape(-1).astype(np.float32), reward, success, truncated, {"goal": self.goal}

    def random_action(self) -> int:
        return int(self.rng.integers(clevr_tasks.NUM_ACTIONS))


def _clevr_distance(ball_xy: np.ndarray, goal: int) -> float:
    source, destination = clevr_tasks.GOAL_SOURCE[goal], clevr_tasks.GOAL_DESTINATION[goal]
    unit = clevr_tasks.RELATION_VECTORS[clevr_tasks.GOAL_RELATION[goal]]
    return float(np.linalg.norm(ball_xy[source] - ball_xy[destination] - clevr_tasks.TARGET_OFFSET * unit))


def _clevr_success(ball_xy: np.ndarray, goal: int) -> bool:
    offset = ball_xy[clevr_tasks.GOAL_SOURCE[goal]] - ball_xy[clevr_tasks.GOAL_DESTINATION[goal]]
    offset = np.where(np.abs(offset) < 1e-3, 0.0, offset)
    angle = np.degrees(np.arctan2(offset[1], offset[0])) % 360.0
    relation = (0, 2, 1, 3)[int(((angle - 45.0) % 360.0) // 90.0)]
    return bool(relation == clevr_tasks.GOAL_RELATION[goal] and np.linalg.norm(offset) < clevr_tasks.SUCCESS_DISTANCE)


class KitchenOriginalEnv:
    """FrankaKitchen as D4RL / TALAR step it, on our kitchen model with the original physics settings.

    Per action: ``q_des = clip(q_obs_prev + 2 a 0.08, pos_bound)`` into the position servos, 40 ``mj_step`` substeps
    of 0.002 s (Euler, Newton 100 iterations / 50 line-search), then the noisy 30-D observation (ratio 0.1), the
    TALAR ``prev_curr`` reward with the posture term and the success test in numpy. Resets restore the fixed
    initial state and draw one of the six sub-tasks. Same lean model as ``envs.make("kitchen")`` (the
    gymnasium-robotics FrankaKitchen-v1 with its mesh model ran at ~327 env steps/s on this kind of machine).
    Action: 9 joint velocities in [-1, 1].
    """

    observation_size = 30
    action_size = 9

    def __init__(self, seed: int = 0, episode_length: int = 280):
        from envs.kitchen import KitchenEnv
        from envs.kitchen import tasks as kitchen_tasks

        env = KitchenEnv(physics="c")  # for the model file and the qpos <-> observation map only
        self.tasks = kitchen_tasks
        self.num_goals = kitchen_tasks.NUM_TASKS
        self.model = mujoco.MjModel.from_xml_path(str(env.xml_path))
        self.model.opt.timestep, self.model.opt.integrator = 0.002, mujoco.mjtIntegrator.mjINT_EULER
        self.model.opt.iterations, self.model.opt.ls_iterations = 100, 50
        self.data = mujoco.MjData(self.model)
        self.init_qpos = env.init_qpos
        self.qpos_index, self.obs_index = env.observation_map
        self.amplitude = 0.1 * kitchen_tasks.NOISE_AMPLITUDE
        self.rng = np.random.default_rng(seed)
        self.episode_length = episode_length

    def _observe(self) -> np.ndarray:
        from envs.kitchen import env as kitchen_env

        obs = self.tasks.INIT_OBS.astype(np.float64)
        obs[self.obs_index] = self.data.qpos[self.qpos_index]
        obs[[10, 12, 14, 16]] = np.clip(obs[[9, 11, 13, 15]] / kitchen_env.KNOB_PER_BURNER, -0.009, 0.0)
        obs[18] = np.clip(obs[17] / kitchen_env.SWITCH_PER_LAMP, -0.05, 0.0)
        return obs + self.amplitude * self.rng.uniform(-1.0, 1.0, obs.shape)

    def _distance(self, obs: np.ndarray) -> float:
        return float(np.linalg.norm(self.tasks.TASK_MASK[self.goal] * (obs - self.tasks.TASK_GOAL[self.goal])))

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = self.init_qpos
        mujoco.mj_forward(self.model, self.data)
        self.obs, self.steps = self._observe(), 0
        self.goal = int(self.rng.integers(self.num_goals))
        self.previous = self._distance(self.obs)
        return self.obs.astype(np.float32), {"goal": self.goal}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        from envs.kitchen import env as kitchen_env

        action = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        self.data.ctrl[:] = np.clip(self.obs[:9] + 2.0 * action * 0.08, kitchen_env.POS_LOW, kitchen_env.POS_HIGH)
        for _ in range(40):
            mujoco.mj_step(self.model, self.data)
        self.obs = self._observe()
        current = self._distance(self.obs)
        success = current < self.tasks.BONUS_THRESH
        reward = self.previous - current + float(success)
        if abs(self.previous - current) <= self.tasks.STILL_THRESH:
            reward -= 0.01 * float(np.linalg.norm(self.obs[:9] - self.tasks.TARGET_POSTURE[self.goal]))
        self.previous, self.steps = current, self.steps + 1
        truncated = not success and self.steps >= self.episode_length
        return self.obs.astype(np.float32), reward, bool(success), truncated, {"goal": self.goal}

    def random_action(self) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, self.action_size)


def steps_per_second(env, num_steps: int) -> float:
    """Env steps per second of a random-action loop with episode resets (steady state after the first reset)."""
    env.reset()
    start = time.perf_counter()
    for _ in range(num_steps):
        _, _, terminated, truncated, _ = env.step(env.random_action())
        if terminated or truncated:
            env.reset()
    return num_steps / (time.perf_counter() - start)


# env name -> the original-style env class (``cls(seed)``); other envs add theirs here.
ORIGINAL_ENVS: dict[str, Callable[..., Any]] = {"clevr": ClevrOriginalEnv, "kitchen": KitchenOriginalEnv}


def original_steps_per_second(name: str, num_steps: int, seed: int = 0) -> float:
    """Steps per second of env ``name`` stepped the original's way."""
    return steps_per_second(ORIGINAL_ENVS[name](seed), num_steps)
