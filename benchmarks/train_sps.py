"""Training throughput (env steps/s of the whole PPO loop: acting + learning) of talar-jax PPO vs an SB3 reference.

``python -m benchmarks.train_sps [--envs clevr kitchen] [--physics c mjx]``

talar-jax: ``make_train`` chunk (jit + vmap, ``num_envs`` envs), timed after compilation. Reference: the
original pipeline's style, stable-baselines3 PPO with 2 envs (DummyVecEnv, n_steps 512, minibatch 128,
10 epochs, [32, 64, 64] tanh, VecNormalize on rewards) driving the original-style numpy envs of
``benchmarks.original_style`` (MuJoCo C stepped from Python, as the original ran; observation = [obs, goal
one-hot]). Needs the ``benchmark`` extra
(``pip install torch==2.13.0`` first, then ``pip install stable-baselines3 gymnasium``).
Prints a table and writes ``benchmarks/results/train_sps.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

import envs
from benchmarks.machine import machine_info
from experiments.cli import ArgumentParser, exit_status
from talar_jax import runtime
from talar_jax.conditioning import GoalOneHotConditioner
from talar_jax.ppo import PPOConfig, derive, make_train

RESULTS = Path(__file__).parent / "results" / "train_sps.json"


def jax_ppo_sps(env_name: str, physics: str, num_envs: int, updates_per_chunk: int, chunks: int) -> dict:
    """Env steps/s of jitted PPO chunks (acting + learning), compile time apart."""
    env = envs.make(env_name, physics=physics)
    config = PPOConfig(num_envs=num_envs, rollout_length=64, updates_per_chunk=updates_per_chunk)
    learner = make_train(config, env, GoalOneHotConditioner(env.num_goals))
    state = jax.jit(jax.vmap(learner.init))(jax.random.split(jax.random.PRNGKey(0), 1))
    start = time.perf_counter()
    chunk = jax.jit(jax.vmap(learner.chunk)).lower(state).compile(compiler_options=learner.compiler_options)
    compile_s = time.perf_counter() - start
    state, _ = chunk(state)  # warm-up
    jax.block_until_ready(state)
    start = time.perf_counter()
    for _ in range(chunks):
        state, _ = chunk(state)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    steps = chunks * derive(config).env_steps_per_chunk
    return {
        "impl": "talar-jax",
        "env": env_name,
        "physics": physics,
        "num_envs": num_envs,
        "env_steps": steps,
        "seconds": seconds,
        "sps": steps / seconds,
        "compile_s": compile_s,
    }


def _original_style_vec_env(env_name: str):
    """2 original-style numpy envs (``benchmarks.original_style``) as SB3's normalised-reward ``DummyVecEnv``,
    observation = [obs, goal one-hot]."""
    import gymnasium
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from benchmarks.original_style import ORIGINAL_ENVS

    class Adapter(gymnasium.Env):
        def __init__(self, seed: int):
            self.env = ORIGINAL_ENVS[env_name](seed)
            size = self.env.observation_size + self.env.num_goals
            self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (size,), np.float32)
            if hasattr(self.env, "num_actions"):
                self.action_space = gymnasium.spaces.Discrete(self.env.num_actions)
            else:
                self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (self.env.action_size,), np.float32)

        def _obs(self, obs: np.ndarray, info: dict) -> np.ndarray:
            return np.concatenate([obs, np.eye(self.env.num_goals, dtype=np.float32)[info["goal"]]])

        def reset(self, *, seed=None, options=None):
            obs, info = self.env.reset(seed)
            return self._obs(obs, info), info

        def step(self, action):
            obs, reward, terminated, truncated, info = self.env.step(action)
            return self._obs(obs, info), reward, terminated, truncated, info

    return VecNormalize(DummyVecEnv([lambda i=i: Adapter(i) for i in range(2)]), norm_obs=False, norm_reward=True)


def sb3_reference_sps(env_name: str, total_steps: int) -> dict:
    """Env steps/s of SB3 PPO with 2 envs driving the original-style numpy env (``benchmarks.original_style``: one
    Python loop of ``mj_step`` substeps per action, as the original pipeline ran), observation = [obs, goal one-hot].
    """
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    vec = _original_style_vec_env(env_name)
    policy_kwargs = {"net_arch": {"pi": [32, 64, 64], "vf": [32, 64, 64]}, "activation_fn": torch.nn.Tanh}
    model = PPO(
        "MlpPolicy",
        vec,
        n_steps=512,
        batch_size=128,
        n_epochs=10,
        learning_rate=3e-4,
        policy_kwargs=policy_kwargs,
        device="cpu",
        seed=0,
    )
    model.learn(total_timesteps=1024)  # warm-up: jit of the adapter, torch initialisation
    start = time.perf_counter()
    model.learn(total_timesteps=total_steps, reset_num_timesteps=False)
    seconds = time.perf_counter() - start
    return {
        "impl": "sb3 original",
        "env": env_name,
        "physics": "c",
        "num_envs": 2,
        "env_steps": total_steps,
        "seconds": seconds,
        "sps": total_steps / seconds,
        "compile_s": 0.0,
    }


def main() -> None:
    runtime.configure(compile_cache=False)  # compile time is part of what benchmarks report
    parser = ArgumentParser(prog="python -m benchmarks.train_sps", description=__doc__)
    parser.add_argument("--envs", nargs="+", default=["clevr", "kitchen"], help="envs to time (default: clevr kitchen)")
    parser.add_argument("--physics", nargs="+", default=["c", "mjx"], help="physics engines to time (default: c mjx)")
    parser.add_argument("--num-envs", type=int, default=64, help="envs of the talar-jax PPO (default: 64)")
    parser.add_argument("--updates-per-chunk", type=int, default=2, help="PPO updates per jitted chunk (default: 2)")
    parser.add_argument("--chunks", type=int, default=2, help="chunks timed after compilation (default: 2)")
    parser.add_argument(
        "--sb3-steps", type=int, default=2048, help="env steps of the stable-baselines3 reference (default: 2048)"
    )
    parser.add_argument("--no-sb3", action="store_true", help="skip the reference (no benchmark extra installed)")
    args = parser.parse_args()
    rows = []
    for env_name in args.envs:
        reference = None if args.no_sb3 else sb3_reference_sps(env_name, args.sb3_steps)
        if reference is not None:
            rows.append({**reference, "ratio": 1.0})
            print(json.dumps(reference), flush=True)
        for physics in args.physics:
            row = jax_ppo_sps(env_name, physics, args.num_envs, args.updates_per_chunk, args.chunks)
            row["ratio"] = row["sps"] / reference["sps"] if reference else None
            rows.append(row)
            print(json.dumps(row), flush=True)
            _write(args, rows)  # after every row: a slow case (MJX kitchen compile on CPU) keeps the others
    print(f"\n{'impl':<14}{'env':<9}{'physics':<8}{'envs':>5}{'steps':>8}{'sps':>10}{'compile s':>11}{'x ref':>7}")
    for r in rows:
        ratio = f"{r['ratio']:.1f}" if r["ratio"] is not None else "-"
        print(
            f"{r['impl']:<14}{r['env']:<9}{r['physics']:<8}{r['num_envs']:>5}{r['env_steps']:>8}{r['sps']:>10.0f}"
            f"{r['compile_s']:>11.1f}{ratio:>7}"
        )
    _write(args, rows)


def _write(args: argparse.Namespace, rows: list[dict]) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    machine = machine_info()
    RESULTS.write_text(json.dumps({"machine": machine, "args": vars(args), "rows": rows}, indent=2))


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
