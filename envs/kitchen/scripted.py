"""Scripted FrankaKitchen controller: IK-solved joint waypoints per sub-task, tracked through the velocity action.

``scripted_action(obs, goal, step)`` is a pure JAX function (jit- and vmap-able): the waypoint tables are
solved once on the host with MuJoCo's C kinematics (damped least squares on the ``end_effector`` site) and
baked in as constants. The action is a proportional law on the joint error plus a gravity feed-forward term
(the servos have no gravity compensation), so it succeeds from the deterministic reset state.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.kitchen import tasks

GAIN = 6.0  # action per rad of joint error
CONTROL_DT = 0.08
_KP = np.array([870.0] * 4 + [120.0] * 3 + [500.0] * 2)
_ARM_LOW = np.array([-2.85, -1.72, -2.85, -3.0, -2.85, 0.05, -2.85])  # joint ranges, joint 6 kept above its
_ARM_HIGH = np.array([2.85, 1.72, 2.85, -0.45, 2.85, 2.08, 2.85])  # servo-target clip at 0
_OPEN, _CLOSED = 0.04, 0.0
_FORWARD, _DOWN, _LEFT = (0.0, 1.0, 0.0), (0.0, 0.0, -1.0), (-1.0, 0.0, 0.0)
_FORWARD_UP = (0.0, 0.7071, 0.7071)


def _microwave_arc(angle: float, z: float) -> tuple[float, float, float]:
    """World position of the microwave handle when the door is at ``angle`` (hinge at (-1.128, 0.455))."""
    c, s = np.cos(angle), np.sin(angle)
    return (-1.128 + 0.486 * c - 0.038 * s, 0.455 + 0.486 * s + 0.038 * c, z)


def _microwave_tangent(angle: float) -> tuple[float, float, float]:
    """Direction the microwave handle moves in when the door opens further from ``angle``."""
    c, s = np.cos(angle), np.sin(angle)
    return (0.038 * c + 0.486 * s, 0.038 * s - 0.486 * c, 0.0)


def _hinge_arc(angle: float) -> tuple[float, float, float]:
    """Where the fingertips pull when the right hinge door is at ``angle``: just behind its handle, 2 cm below the
    handle's middle (hinge at (-0.224, 0.71); the point sits 0.321 m left of and 0.08 m in front of the hinge at
    angle 0). The gripper points forward and up there: pointing straight forward, the arm cannot reach it."""
    c, s = np.cos(angle), np.sin(angle)
    return (-0.224 - 0.321 * c + 0.08 * s, 0.71 - 0.321 * s - 0.08 * c, 2.58)


# Per task: waypoints (TCP position, gripper pointing axis, finger-opening axis or None, fingers, steps to reach).
_PLANS: dict[str, list[tuple[tuple[float, float, float], tuple, tuple | None, float, int]]] = {
    "microwave": [
        ((-0.645, 0.42, 1.97), _DOWN, _microwave_tangent(0.0), _OPEN, 45),
        ((-0.645, 0.493, 1.97), _DOWN, _microwave_tangent(0.0), _OPEN, 20),
        ((-0.645, 0.493, 1.97), _DOWN, _microwave_tangent(0.0), _OPEN, 15),
        ((-0.645, 0.493, 1.86), _DOWN, _microwave_tangent(0.0), _OPEN, 20),
        *[(_microwave_arc(a, 1.86), _DOWN, _microwave_tangent(a), _OPEN, 20) for a in (-0.2, -0.4, -0.6, -0.8)],
    ],
    "kettle": [
        ((-0.27, 0.17, 1.85), _DOWN, (1.0, 0.0, 0.0), _OPEN, 50),
        ((-0.27, 0.17, 1.70), _DOWN, (1.0, 0.0, 0.0), _OPEN, 25),
        ((-0.26, 0.33, 1.70), _DOWN, (1.0, 0.0, 0.0), _OPEN, 35),
        ((-0.25, 0.48, 1.70), _DOWN, (1.0, 0.0, 0.0), _OPEN, 35),
    ],
    "light switch": [
        ((-0.31, 0.58, 2.28), _FORWARD, None, _CLOSED, 40),
        ((-0.32, 0.635, 2.28), _FORWARD, None, _CLOSED, 20),
        ((-0.43, 0.635, 2.28), _FORWARD, None, _CLOSED, 30),
    ],
    "slide cabinet": [
        ((-0.17, 0.55, 2.50), _FORWARD, None, _CLOSED, 45),
        ((-0.17, 0.62, 2.50), _FORWARD, None, _CLOSED, 20),
        ((-0.06, 0.62, 2.50), _FORWARD, None, _CLOSED, 25),
        ((0.05, 0.62, 2.50), _FORWARD, None, _CLOSED, 25),
    ],
    "top burner": [
        ((-0.31, 0.60, 2.372), _FORWARD, None, _CLOSED, 45),
        ((-0.31, 0.655, 2.372), _FORWARD, None, _CLOSED, 20),
        ((-0.21, 0.655, 2.372), _FORWARD, None, _CLOSED, 35),
        ((-0.21, 0.60, 2.372), _FORWARD, None, _CLOSED, 20),
    ],
    "bottom burner": [
        ((-0.31, 0.60, 2.258), _FORWARD, None, _CLOSED, 45),
        ((-0.31, 0.655, 2.258), _FORWARD, None, _CLOSED, 20),
        ((-0.225, 0.655, 2.258), _FORWARD, None, _CLOSED, 35),
        ((-0.225, 0.60, 2.258), _FORWARD, None, _CLOSED, 20),
    ],
    "hinge cabinet": [
        ((-0.44, 0.55, 2.58), _FORWARD_UP, None, _CLOSED, 45),
        ((-0.44, 0.63, 2.58), _FORWARD_UP, None, _CLOSED, 20),
        (_hinge_arc(0.0), _FORWARD_UP, None, _CLOSED, 25),
        *[(_hinge_arc(a), _FORWARD_UP, None, _CLOSED, 20) for a in (0.3, 0.6, 0.9, 1.2, 1.5)],
    ],
}
NUM_WAYPOINTS = max(len(plan) for plan in _PLANS.values())


def _solve_ik(model, data, site, target_pos, z_axis, y_axis, q_seed, iterations=300) -> np.ndarray:
    """Damped-least-squares IK of the 7 arm joints for the site position and gripper axes."""
    q = q_seed.copy()
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for _ in range(iterations):
        data.qpos[:7] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        rot = data.site_xmat[site].reshape(3, 3)
        errors = [np.asarray(target_pos) - data.site_xpos[site], np.cross(rot[:, 2], z_axis)]
        if y_axis is not None:
            errors.append(np.cross(rot[:, 1], y_axis))
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        jac = np.vstack([jacp[:, :7]] + [jacr[:, :7]] * (len(errors) - 1))
        err = np.concatenate(errors)
        if np.linalg.norm(err) < 1e-5:
            break
        dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-3 * np.eye(len(err)), err)
        q = np.clip(q + np.clip(dq, -0.2, 0.2), _ARM_LOW, _ARM_HIGH)
    return q


def _solve_best(model, data, site, target_pos, z_axis, y_axis, q_previous) -> np.ndarray:
    """IK from the previous waypoint, falling back to other seeds (reset and TALAR postures) if it gets stuck."""
    if y_axis is not None:
        y_axis = y_axis - y_axis.dot(z_axis) * z_axis
        y_axis = y_axis / np.linalg.norm(y_axis)
    seeds = [q_previous, tasks.INIT_OBS[:7], *tasks.TARGET_POSTURE[:, :7]]
    best, best_error = q_previous, np.inf
    for seed in seeds:
        q = _solve_ik(model, data, site, target_pos, z_axis, y_axis, np.asarray(seed, np.float64))
        data.qpos[:7] = q
        mujoco.mj_kinematics(model, data)
        error = np.linalg.norm(data.site_xpos[site] - target_pos) + 0.1 * np.linalg.norm(
            data.site_xmat[site].reshape(3, 3)[:, 2] - z_axis
        )
        if error < 2e-3:
            return q
        if error < best_error:
            best, best_error = q, error
    return best


@functools.lru_cache(maxsize=1)
def waypoint_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solves every plan once.

    Returns:
        waypoints (7, W, 9) joint targets, feedforward (7, W, 9) gravity actions, ends (7, W) int32 step at
        which each waypoint is reached (targets are interpolated linearly in between; later padding repeats).
    """
    from envs.kitchen.env import KitchenEnv  # local: the env module imports nothing from here

    model = mujoco.MjModel.from_xml_path(str(KitchenEnv.xml_path))
    data = mujoco.MjData(model)
    init_qpos = KitchenEnv(physics="c").init_qpos
    site = model.site("end_effector").id
    waypoints = np.zeros((len(tasks.ALL_TASK_NAMES), NUM_WAYPOINTS, 9))
    feedforward = np.zeros_like(waypoints)
    ends = np.zeros((len(tasks.ALL_TASK_NAMES), NUM_WAYPOINTS), np.int32)
    for goal, name in enumerate(tasks.ALL_TASK_NAMES):
        q, step = init_qpos[:7].astype(np.float64), 0
        for k in range(NUM_WAYPOINTS):
            if k < len(_PLANS[name]):
                pos, z_axis, y_axis, fingers, duration = _PLANS[name][k]
                y_axis = None if y_axis is None else np.asarray(y_axis)
                q = _solve_best(model, data, site, pos, np.asarray(z_axis), y_axis, q)
                step += duration
            waypoints[goal, k] = np.concatenate([q, [fingers, fingers]])
            data.qpos[:] = init_qpos
            data.qpos[:9] = waypoints[goal, k]
            data.qvel[:] = 0.0
            mujoco.mj_forward(model, data)
            feedforward[goal, k, :7] = data.qfrc_bias[:7] / (_KP[:7] * 2.0 * CONTROL_DT)
            ends[goal, k] = step
    return waypoints.astype(np.float32), feedforward.astype(np.float32), ends


def scripted_action(obs: jax.Array, goal: jax.Array, step: jax.Array) -> jax.Array:
    """The scripted action for sub-task ``goal`` at env step ``step``.

    Args:
        obs: (30,) observation (only the 9 robot joints are used).
        goal: () int goal id (index in ``tasks.ALL_TASK_NAMES``).
        step: () int steps since reset.

    Returns:
        (9,) action in [-1, 1].
    """
    waypoints, feedforward, ends = (jnp.asarray(table) for table in waypoint_tables())
    ends_goal = ends[goal]  # (W,)
    starts = jnp.concatenate([jnp.zeros(1, ends_goal.dtype), ends_goal[:-1]])
    k = jnp.minimum(jnp.sum(step >= ends_goal), NUM_WAYPOINTS - 1)
    previous = jnp.where(k > 0, waypoints[goal, jnp.maximum(k - 1, 0)], jnp.asarray(tasks.INIT_OBS[:9]))
    fraction = jnp.clip((step - starts[k] + 1) / jnp.maximum(ends_goal[k] - starts[k], 1), 0.0, 1.0)
    target = previous + fraction * (waypoints[goal, k] - previous)
    return jnp.clip(GAIN * (target - obs[: tasks.NUM_ROBOT_JOINTS]) + feedforward[goal, k], -1.0, 1.0)


def noisy_scripted_action(state, rng: jax.Array, noise_scale: float = 0.1) -> jax.Array:
    """The scripted action for the state's own sub-task plus Gaussian exploration noise (one env, jit-able).

    Reads the step count from ``state.info["steps"]``, which ``envs.wrappers.EpisodeWrapper`` (the time limit)
    adds. Used to collect a task dataset that covers every sub-task.
    """
    if "steps" not in state.info:
        raise ValueError(
            "noisy_scripted_action needs state.info['steps']: wrap the env in envs.wrappers.EpisodeWrapper"
        )
    action = scripted_action(state.obs, state.task.goal, state.info["steps"])
    noise = noise_scale * jax.random.normal(rng, action.shape, action.dtype)
    return jnp.clip(action + noise, -1.0, 1.0)
