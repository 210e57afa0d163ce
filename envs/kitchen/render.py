"""Render a scripted FrankaKitchen rollout to a GIF: ``python -m envs.kitchen.render --task microwave``.

Needs an OpenGL backend. On a headless Linux machine set ``MUJOCO_GL=egl`` (Debian/Ubuntu packages
``libegl1`` + ``libgl1``; with a GPU the vendor's EGL) or ``MUJOCO_GL=osmesa`` (``libosmesa6``) before starting
Python.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.kitchen import scripted, tasks
from envs.kitchen.env import KitchenEnv


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


def render_frames(model: mujoco.MjModel, qpos: np.ndarray, width: int = 320, height: int = 240) -> list[np.ndarray]:
    """(T, nq) joint positions -> list of (height, width, 3) uint8 frames. Raises if no GL backend works."""
    data = mujoco.MjData(model)
    camera = mujoco.MjvCamera()
    camera.lookat[:] = (-0.4, 0.45, 1.95)
    camera.distance, camera.azimuth, camera.elevation = 2.3, 112.0, -28.0
    frames = []
    with mujoco.Renderer(model, height, width) as renderer:
        for q in qpos:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera)
            frames.append(renderer.render().copy())
    return frames


def write_gif(frames: list[np.ndarray], path: Path, frame_seconds: float) -> None:
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 * frame_seconds), loop=0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="microwave", choices=tasks.TASK_NAMES)
    parser.add_argument("--out", type=Path, default=None, help="GIF path (default kitchen_<task>.gif)")
    parser.add_argument("--physics", default="c", choices=("c", "mjx"))
    parser.add_argument("--every", type=int, default=2, help="keep every n-th env step")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    args = parser.parse_args(argv)
    out = args.out or Path(f"kitchen_{args.task.replace(' ', '_')}.gif")
    env = KitchenEnv(physics=args.physics)
    qpos, first = scripted_qpos_trajectory(env, args.task)
    end = first + 2 if first >= 0 else len(qpos)
    try:
        frames = render_frames(env.mj_model, qpos[: end : args.every], args.width, args.height)
    except Exception as error:  # no GL context: say how to get one
        print(f"rendering failed ({error}); set MUJOCO_GL=egl or MUJOCO_GL=osmesa (see module docstring)")
        return 2
    frames += [frames[-1]] * 5  # linger on the final frame
    write_gif(frames, out, frame_seconds=0.08 * args.every)
    print(f"{args.task}: success at step {first}; wrote {len(frames)} frames to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
