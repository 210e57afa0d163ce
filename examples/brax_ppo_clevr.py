"""Brax's own PPO (``brax.training.agents.ppo.train``) learns CLEVR-Robot's 80 push goals with the goal observed.

    python examples/brax_ppo_clevr.py [--timesteps 5000000] [--seed 0] [--out results/envs-library/brax-ppo-clevr.json]

Nothing here imports ``talar_jax``: the env comes from ``envs.make("clevr", goal_observation=True)`` (10-D ball
positions + 14-D goal one-hots) and goes to Brax unchanged through ``envs.wrap_for_brax_training``. Brax's policy
emits 40 float scores per step; the env takes their argmax as the push. At the end the deterministic policy is
evaluated on 2,000 fresh episodes (success = the goal relation holds within 50 pushes).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as ppo
from provenance import provenance  # examples/provenance.py: examples/ is on sys.path when run as a script

import envs

CPU_XLA_FLAG = "--xla_cpu_use_fusion_emitters=false"
"""MJX's CPU flag; XLA reads XLA_FLAGS when JAX's backend starts (its first computation), so ``main`` sets it first."""


def evaluate(env, policy, episodes: int, seed: int) -> float:
    """Success rate of ``policy`` over ``episodes`` fresh episodes (one jitted, vmapped rollout)."""

    def episode(key):
        reset_key, act_key = jax.random.split(key)
        state = env.reset(reset_key)

        def body(carry, step_key):
            state, succeeded = carry
            action = policy(state.obs, step_key)[0]
            state = jax.lax.cond(succeeded > 0, lambda s: s, lambda s: env.step(s, action), state)
            return (state, jnp.maximum(succeeded, state.metrics["success"])), None

        (_, succeeded), _ = jax.lax.scan(body, (state, jnp.float32(0)), jax.random.split(act_key, env.episode_length))
        return succeeded

    keys = jax.random.split(jax.random.key(seed), episodes)
    return float(jnp.mean(jax.jit(jax.vmap(episode))(keys)))


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=5_000_000, help="env steps of training")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--physics", choices=envs.PHYSICS_NAMES, default="c")
    parser.add_argument("--out", type=Path, default=Path("results/envs-library/brax-ppo-clevr.json"))
    args = parser.parse_args(argv)
    if args.timesteps < 100_000:
        parser.error("--timesteps must be >= 100000")
    return args


def train(
    env,
    timesteps: int,
    seed: int,
    progress,
    *,
    num_envs: int = 256,
    hidden: tuple[int, ...] = (256, 256),
    num_minibatches: int = 8,
    num_updates_per_batch: int = 4,
    num_evals: int = 11,
):
    """Brax's PPO on ``env`` (``progress(step, metrics)`` after each evaluation); returns (make_policy, params).

    The keyword defaults are the recorded run's; tests/test_brax_ppo.py trains a tiny one with smaller values.
    ``num_envs`` also sets the batch size and the evaluation envs; ``hidden`` is both networks' hidden layers.
    """
    network_factory = functools.partial(
        ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=hidden, value_hidden_layer_sizes=hidden
    )
    make_policy, params, _ = ppo.train(
        environment=env,
        num_timesteps=timesteps,
        episode_length=env.episode_length,
        wrap_env_fn=envs.wrap_for_brax_training,
        num_envs=num_envs,
        batch_size=num_envs,
        num_minibatches=num_minibatches,
        unroll_length=10,
        num_updates_per_batch=num_updates_per_batch,
        learning_rate=3e-4,
        entropy_cost=1e-2,
        discounting=0.97,
        reward_scaling=0.1,
        normalize_observations=True,
        num_evals=num_evals,
        num_eval_envs=num_envs,
        network_factory=network_factory,
        progress_fn=progress,
        seed=seed,
    )
    return make_policy, params


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("XLA_FLAGS", CPU_XLA_FLAG)
    args = parse_args(argv)
    env = envs.make("clevr", physics=args.physics, goal_observation=True)
    start = time.perf_counter()
    curve = []

    def progress(step, metrics):
        success = float(metrics.get("eval/episode_success", float("nan")))
        curve.append({"env_steps": int(step), "success": success, "seconds": round(time.perf_counter() - start, 1)})
        print(f"{step:>10,d} env steps  eval success {success:.3f}  {time.perf_counter() - start:7.0f} s", flush=True)

    make_policy, params = train(env, args.timesteps, args.seed, progress)
    train_seconds = time.perf_counter() - start
    success = evaluate(env, make_policy(params, deterministic=True), episodes=2000, seed=args.seed + 1)
    summary = {
        "env": "clevr",
        "options": {"goal_observation": True},
        "physics": args.physics,
        "trainer": "brax.training.agents.ppo.train",
        "env_steps": args.timesteps,
        "seed": args.seed,
        "train_seconds": round(train_seconds, 1),
        "final_success_deterministic_2000_episodes": success,
        "curve": curve,
        **provenance(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    print(
        f"success {success:.3f} on 2000 episodes after {args.timesteps:,d} env steps, {train_seconds:.0f} s "
        f"-> {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
