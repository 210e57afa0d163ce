"""Render a scripted FrankaKitchen rollout to a GIF: ``python -m envs.kitchen.render --task microwave``.

Needs OpenGL: on a headless Linux machine EGL (Debian/Ubuntu packages ``libegl1`` + ``libgl1``; with a GPU the vendor's
EGL) or OSMesa (``libosmesa6``), which ``envs.render`` picks by itself when ``MUJOCO_GL`` is not set.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from envs.kitchen import scripted, tasks
from envs.kitchen.env import KitchenEnv
from envs.physics import PHYSICS_NAMES
from envs.render import RenderError, write_video


def scripted_qpos_trajectory(env: KitchenEnv, task: str, seed: int = 0) -> tuple[np.ndarray, int]:
    """Runs the scripted controller for one sub-task until success (or the episode ends).

    Returns:
        ((T + 1, nq) qpos trajectory including the reset state, index of the first successful step or -1).
    """
    goal = jnp.int32(tasks.task_id(task))

    def rollout(key):
        state = env.reset(key)
        state = state.replace(task=state.task.replace(goal=goal))

        def body(state, step):
            next_state = env.step(state, scripted.scripted_action(state.obs, goal, step))
            return next_state, (next_state.data.qpos, next_state.metrics["success"])

        return state.data.qpos, jax.lax.scan(body, state, jnp.arange(env.episode_length))[1]

    qpos0, (qpos, success) = jax.jit(rollout)(jax.random.key(seed))
    success = np.asarray(success) > 0.5
    first = int(np.argmax(success)) if success.any() else -1
    return np.concatenate([np.asarray(qpos0)[None], np.asarray(qpos)]), first


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="microwave", choices=tasks.TASK_NAMES)
    parser.add_argument("--out", type=Path, default=None, help="GIF path (default kitchen_<task>.gif)")
    parser.add_argument("--physics", default="c", choices=PHYSICS_NAMES)
    parser.add_argument("--every", type=int, default=2, help="keep every n-th env step")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    args = parser.parse_args(argv)
    out = args.out or Path(f"kitchen_{args.task.replace(' ', '_')}.gif")
    env = KitchenEnv(physics=args.physics)
    qpos, first = scripted_qpos_trajectory(env, args.task)
    end = first + 2 if first >= 0 else len(qpos)
    try:
        frames = env.render(qpos[: end : args.every], args.width, args.height)
    except RenderError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    frames += [frames[-1]] * 5  # linger on the final frame
    write_video(frames, out, fps=1.0 / (0.08 * args.every))
    print(f"{args.task}: success at step {first}; wrote {len(frames)} frames to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
