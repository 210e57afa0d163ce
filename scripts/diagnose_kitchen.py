"""Why does the kitchen instruction follower fail some sub-tasks? Two measurements.

``python scripts/diagnose_kitchen.py reward``: the reward terms along the scripted controller's episodes, per
sub-task (does the shaping point towards success, and how many steps does success take?).

``python scripts/diagnose_kitchen.py ppo --out runs/diag/base [--ppo.normalize-observations] [--ppo.num-envs 256]``:
PPO given the goal itself (one-hot, as the oracle), several seeds vmapped; prints success per sub-task and the
policy's standard deviation over training, so a setting can be judged per sub-task without the language stages.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")

import jax
import jax.numpy as jnp
import numpy as np
import tyro

import envs
from envs.kitchen import tasks
from envs.kitchen.scripted import scripted_action
from talar_jax.conditioning import GoalOneHotConditioner
from talar_jax.ppo import PPOConfig, run_ppo


@dataclasses.dataclass(frozen=True)
class Reward:
    """Reward terms along scripted episodes."""

    episodes: int = 32
    """Episodes per sub-task."""
    noise: float = 0.1
    """Std of the Gaussian action noise (the task dataset's collector uses 0.1)."""
    physics: str = "c"
    posture_targets: str = "talar"
    """The env's posture-term targets: 'talar' or 'scripted'."""
    behaviour: str = "scripted"
    """'scripted' (the IK controller that succeeds) or 'posture' (drive the arm to the target posture and hold it:
    the local optimum the posture term offers)."""


@dataclasses.dataclass(frozen=True)
class Ppo:
    """Goal-conditioned PPO on the kitchen."""

    out: Path = Path("runs/diag/kitchen")
    physics: str = "c"
    posture_targets: str = "talar"
    """The env's posture-term targets: 'talar' or 'scripted'."""
    ppo: PPOConfig = PPOConfig(
        num_seeds=3, total_env_steps=1_000_000, eval_every_chunks=2, eval_episodes=120, eval_deterministic=False
    )


def reward_along_scripted(args: Reward) -> None:
    env = envs.make("kitchen", physics=args.physics, posture_targets=args.posture_targets)
    targets = tasks.POSTURE_TARGETS[args.posture_targets]

    def episode(goal: jax.Array, rng: jax.Array):
        rng_reset, rng_loop = jax.random.split(rng)
        state = env.reset(rng_reset)
        state = state.replace(task=state.task.replace(goal=goal))

        def step(carry, inputs):
            state, done = carry
            rng_step, t = inputs
            if args.behaviour == "posture":
                action = 6.0 * (jnp.asarray(targets)[goal] - state.obs[:9])
            else:
                action = scripted_action(state.obs, goal, t)
            action = action + args.noise * jax.random.normal(rng_step, (9,))
            action = jnp.clip(action, -1.0, 1.0)
            nxt = env.step(state, action)
            terms = tasks.single_task_reward(
                state.task.distance[goal], nxt.task.distance[goal], nxt.obs[: tasks.NUM_ROBOT_JOINTS], goal, targets
            )
            alive = 1.0 - done
            out = {k: v * alive for k, v in terms.items()} | {"alive": alive}
            return (nxt, jnp.maximum(done, nxt.done)), out

        length = env.config.episode_length
        steps = (jax.random.split(rng_loop, length), jnp.arange(length))
        _, out = jax.lax.scan(step, (state, jnp.float32(0.0)), steps)
        return jax.tree.map(lambda x: jnp.sum(x, 0), out)

    run = jax.jit(jax.vmap(episode))
    print("| sub-task | success | steps (mean) | progress sum | posture sum | success bonus | total |")
    print("|---|---|---|---|---|---|---|")
    for goal, name in enumerate(tasks.TASK_NAMES):
        keys = jax.random.split(jax.random.PRNGKey(goal), args.episodes)
        out = jax.device_get(run(jnp.full((args.episodes,), goal, jnp.int32), keys))
        total = out["progress"] + out["posture"] + out["success"]
        print(
            f"| {name} | {out['success'].mean():.2f} | {out['alive'].mean():.0f} | {out['progress'].mean():.3f} | "
            f"{out['posture'].mean():.3f} | {out['success'].mean():.2f} | {total.mean():.3f} |"
        )


def goal_conditioned_ppo(args: Ppo) -> None:
    env = envs.make("kitchen", physics=args.physics, posture_targets=args.posture_targets)
    result = run_ppo(args.ppo, env, GoalOneHotConditioner(env.num_goals), args.out, eval_splits=("train",))
    rows = [json.loads(line) for line in (args.out / "metrics.jsonl").read_text().splitlines()]
    print("| env steps | std | " + " | ".join(tasks.TASK_NAMES) + " | mean |")
    print("|---|---|" + "---|" * (tasks.NUM_TASKS + 1))
    for row in rows:
        if "eval/train/success_per_goal" not in row:
            continue
        per_goal = [100 * v for v in row["eval/train/success_per_goal"]]
        cells = " | ".join(f"{v:.0f}" for v in per_goal)
        print(
            f"| {row['train/env_steps']} | {row.get('policy/std', float('nan')):.3f} | {cells} | "
            f"{100 * row['eval/train/success']:.1f} |"
        )
    print(
        f"per seed: {np.round(result.final_eval['train']['success_per_seed'], 3).tolist()}, wall {result.wall_s:.0f} s"
    )


if __name__ == "__main__":
    command = tyro.extras.subcommand_cli_from_dict({"reward": Reward, "ppo": Ppo})
    (reward_along_scripted if isinstance(command, Reward) else goal_conditioned_ppo)(command)
