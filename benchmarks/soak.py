"""Soak test: every registered env, 10^6 random-action steps per physics engine (batched, with auto-reset).

    python -m benchmarks.soak [--steps 1000000] [--batch 1000] [--envs clevr kitchen] [--physics c mjx]

Reports per (env, backend): steps, non-finite counts (obs, reward, qpos, qvel), the largest joint speed, the largest
joint-limit violation (qpos outside a limited hinge/slide joint's range) and the number of env steps where it exceeds
``BLOWUP`` (a constraint blow-up), plus steps/s. Writes a markdown table and JSON to ``--out``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import envs
from experiments.cli import ArgumentParser, exit_status
from talar_jax import runtime

BLOWUP = 0.1
"""A joint further than this (rad or m) outside its range counts as a constraint blow-up."""
CHUNK = 50
"""Env steps per jitted call."""


def _limited_joints(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos addresses and (low, high) ranges of the limited hinge and slide joints."""
    hinge_slide = (model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE) | (model.jnt_type == mujoco.mjtJoint.mjJNT_SLIDE)
    joints = np.flatnonzero(hinge_slide & model.jnt_limited.astype(bool))
    return model.jnt_qposadr[joints], model.jnt_range[joints, 0], model.jnt_range[joints, 1]


def soak(name: str, physics: str, steps: int, batch: int, seed: int) -> dict:
    """Runs ``steps`` env steps of ``name`` on ``physics`` and returns the statistics."""
    env = envs.make(name, physics=physics)
    wrapped = envs.wrap_for_training(env)
    address, low, high = (jnp.asarray(a) for a in _limited_joints(env.mj_model))
    spec = env.action_spec

    def actions(key):
        if spec.kind == "discrete":
            return jax.random.randint(key, (CHUNK, batch), 0, spec.size)
        return jax.random.uniform(key, (CHUNK, batch, spec.size), minval=spec.low, maxval=spec.high)

    def chunk(state, key):
        def body(state, action):
            state = jax.vmap(wrapped.step)(state, action)
            qpos, qvel = state.data.qpos, state.data.qvel
            violation = jnp.maximum(low - qpos[:, address], qpos[:, address] - high).max(axis=1, initial=0.0)
            stats = {
                "nonfinite_obs": jnp.sum(~jnp.isfinite(state.obs).all(axis=1)),
                "nonfinite_reward": jnp.sum(~jnp.isfinite(state.reward)),
                "nonfinite_qpos": jnp.sum(~jnp.isfinite(qpos).all(axis=1)),
                "nonfinite_qvel": jnp.sum(~jnp.isfinite(qvel).all(axis=1)),
                "max_joint_speed": jnp.nanmax(jnp.abs(qvel)),
                "max_limit_violation": jnp.nanmax(violation),
                "blowups": jnp.sum(violation > BLOWUP),
                "successes": jnp.sum(state.metrics["success"]),
            }
            return state, stats

        state, stats = jax.lax.scan(body, state, actions(key))
        reduce = {k: (jnp.max if k.startswith("max") else jnp.sum)(v) for k, v in stats.items()}
        return state, reduce

    key = jax.random.key(seed)
    state = jax.jit(jax.vmap(wrapped.reset))(jax.random.split(key, batch))
    chunk_jit = jax.jit(chunk)
    totals: dict[str, float] = {}
    calls = -(-steps // (CHUNK * batch))
    start = None
    for i in range(calls):
        state, stats = chunk_jit(state, jax.random.fold_in(key, i))
        stats = jax.device_get(stats)
        if start is None:
            start = time.perf_counter()  # after the first call (compile)
        for k, v in stats.items():
            totals[k] = max(totals.get(k, 0.0), float(v)) if k.startswith("max") else totals.get(k, 0.0) + float(v)
        if (i + 1) % max(1, calls // 10) == 0:
            print(f"  {name} {physics}: {(i + 1) * CHUNK * batch:,d} steps", flush=True)
    seconds = time.perf_counter() - start
    done_steps = calls * CHUNK * batch
    return {
        "env": name,
        "physics": physics,
        "steps": done_steps,
        "batch": batch,
        **{k: (v if k.startswith("max") else int(v)) for k, v in totals.items()},
        "steps_per_s": (calls - 1) * CHUNK * batch / seconds if calls > 1 else float("nan"),
    }


def table(rows: list[dict]) -> str:
    header = (
        "| env | physics | env steps | non-finite obs / reward / qpos / qvel | max joint speed | "
        f"max limit violation | steps with violation > {BLOWUP} | successes | steps/s |"
    )
    lines = [header, "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        nonfinite = " / ".join(
            str(r[k]) for k in ("nonfinite_obs", "nonfinite_reward", "nonfinite_qpos", "nonfinite_qvel")
        )
        lines.append(
            f"| {r['env']} | {r['physics']} | {r['steps']:,d} | {nonfinite} | {r['max_joint_speed']:.2f} | "
            f"{r['max_limit_violation']:.4f} | {r['blowups']} | {r['successes']:,d} | {r['steps_per_s']:,.0f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    runtime.configure(compile_cache=False)
    parser = ArgumentParser(prog="python -m benchmarks.soak", description=__doc__)
    parser.add_argument("--steps", type=int, default=1_000_000, help="env steps per env and backend (default: 1000000)")
    parser.add_argument("--batch", type=int, default=1000, help="envs stepped together (default: 1000)")
    parser.add_argument(
        "--mjx-kitchen-steps",
        type=int,
        default=None,
        help="env steps of the kitchen envs on MJX (default --steps; on a CPU, MJX runs the arm at ~300 steps/s)",
    )
    parser.add_argument(
        "--envs", nargs="+", default=list(envs.ALL_ENVS), choices=envs.ALL_ENVS, help="envs to soak (default: all)"
    )
    parser.add_argument(
        "--physics",
        nargs="+",
        default=list(envs.PHYSICS_NAMES),
        choices=envs.PHYSICS_NAMES,
        help="physics engines to soak (default: all)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the resets and random actions (default: 0)")
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results/envs-library/soak"),
        help="folder of the report (default: results/envs-library/soak)",
    )
    args = parser.parse_args(argv)
    if args.steps < 1 or args.batch < 1 or (args.mjx_kitchen_steps is not None and args.mjx_kitchen_steps < 1):
        parser.error("--steps and --batch must be >= 1")
    rows = []
    for name in args.envs:
        for physics in args.physics:
            steps = args.steps
            if physics == "mjx" and name.startswith("kitchen") and args.mjx_kitchen_steps is not None:
                steps = args.mjx_kitchen_steps
            rows.append(soak(name, physics, steps, args.batch, args.seed))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    text = f"Command: `python {' '.join(sys.argv)}`\n\n{table(rows)}\n"
    (args.out / "soak.md").write_text(text)
    (args.out / "soak.json").write_text(json.dumps({"command": "python " + " ".join(sys.argv), "rows": rows}, indent=2))
    print("\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
