"""stable-baselines3 PPO learns one FrankaKitchen sub-task through the Gymnasium adapter (batched MuJoCo C physics).

    pip install -e .[gymnasium] stable-baselines3   # after: pip install torch==2.13.0 (a CPU build)
    python examples/sb3_ppo_kitchen.py [--task "slide cabinet"] [--timesteps 300000] [--num-envs 16]

The env is ``envs.to_gymnasium_vector("kitchen", num_envs, goal=<sub-task id>, posture_targets="scripted")``: every
episode asks for the same sub-task, with TALAR's reward (progress on the object, +1 on success, a posture term).
A 25-line ``VecEnv`` below hands SB3 the whole batch, so each SB3 step is one jitted call that steps every env in
MuJoCo's C engine at once. Progress is the success rate and return of the episodes finished in each window of
env steps, written with the command to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from provenance import provenance  # examples/provenance.py: examples/ is on sys.path when run as a script
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

import envs
from envs.kitchen import tasks

CPU_XLA_FLAG = "--xla_cpu_use_fusion_emitters=false"
"""MJX's CPU flag; XLA reads XLA_FLAGS when JAX's backend starts (its first computation), so ``main`` sets it first."""


class BatchedVecEnv(VecEnv):
    """SB3's ``VecEnv`` over an ``envs.to_gymnasium_vector`` batch (same-step auto-reset, as SB3 expects)."""

    def __init__(self, vector_env):
        self.vector_env = vector_env
        super().__init__(vector_env.num_envs, vector_env.single_observation_space, vector_env.single_action_space)
        self._actions = None

    def reset(self):
        return self.vector_env.reset(seed=self._seeds[0] if self._seeds[0] is not None else None)[0]

    def step_async(self, actions):
        self._actions = np.clip(actions, -1.0, 1.0)

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.vector_env.step(self._actions)
        infos = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(terminated | truncated):
            infos[i] = {
                "terminal_observation": info["final_obs"][i],
                "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                "success": float(info["final_info"]["success"][i]),
            }
        return obs, reward.astype(np.float32), terminated | truncated, infos

    def close(self):
        self.vector_env.close()

    def get_attr(self, attr_name, indices=None):
        return [getattr(self.vector_env, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.vector_env, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        raise NotImplementedError("the batch is one env object")

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._get_indices(indices))


class EpisodeLog(BaseCallback):
    """Success rate and return of the episodes that ended in each window of ``every`` env steps."""

    def __init__(self, every: int, num_envs: int):
        super().__init__()
        self.every, self.windows, self.returns = every, [], np.zeros(num_envs)
        self.successes, self.episode_returns, self.start = [], [], time.perf_counter()

    def _on_step(self) -> bool:
        self.returns += self.locals["rewards"]
        for i, info in enumerate(self.locals["infos"]):
            if "success" in info:
                self.successes.append(info["success"])
                self.episode_returns.append(self.returns[i])
                self.returns[i] = 0.0
        if self.num_timesteps // self.every > len(self.windows) and self.successes:
            window = {
                "env_steps": self.num_timesteps,
                "episodes": len(self.successes),
                "success": float(np.mean(self.successes)),
                "return": float(np.mean(self.episode_returns)),
                "seconds": round(time.perf_counter() - self.start, 1),
            }
            self.windows.append(window)
            print(
                f"{window['env_steps']:>9,d} env steps  success {window['success']:.3f}  return {window['return']:7.3f}"
                f"  ({window['episodes']} episodes)  {window['seconds']:6.0f} s",
                flush=True,
            )
            self.successes, self.episode_returns = [], []
        return True


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("XLA_FLAGS", CPU_XLA_FLAG)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="slide cabinet", choices=tasks.ALL_TASK_NAMES)
    parser.add_argument("--timesteps", type=int, default=300_000)
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results/envs-library/sb3-ppo-kitchen.json"))
    args = parser.parse_args(argv)
    if args.timesteps < 10_000 or args.num_envs < 1:
        parser.error("--timesteps must be >= 10000 and --num-envs >= 1")

    goal = tasks.task_id(args.task)
    options = {"posture_targets": "scripted", "hinge_cabinet_task": args.task == "hinge cabinet"}
    vector_env = envs.to_gymnasium_vector("kitchen", args.num_envs, physics="c", goal=goal, **options)
    vec_env = BatchedVecEnv(vector_env)
    vec_env.seed(args.seed)
    model = PPO("MlpPolicy", vec_env, n_steps=256, batch_size=512, learning_rate=3e-4, gamma=0.99, seed=args.seed)
    log = EpisodeLog(every=max(args.timesteps // 15, 280 * args.num_envs), num_envs=args.num_envs)
    start = time.perf_counter()
    model.learn(total_timesteps=args.timesteps, callback=log)
    summary = {
        "env": "kitchen",
        "task": args.task,
        "goal_id": goal,
        "options": options,
        "trainer": "stable_baselines3.PPO (MlpPolicy, n_steps 256, batch 512)",
        "num_envs": args.num_envs,
        "env_steps": args.timesteps,
        "seed": args.seed,
        "train_seconds": round(time.perf_counter() - start, 1),
        "windows": log.windows,
        **provenance(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    first, last = log.windows[0], log.windows[-1]
    print(
        f"success {first['success']:.3f} -> {last['success']:.3f}, return {first['return']:.2f} -> {last['return']:.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
