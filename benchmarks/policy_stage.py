"""Where a policy stage's time goes, per PPO update: physics, acting, learning, evaluation, beside the learner's floor.

``python -m benchmarks.policy_stage [--envs clevr kitchen] [--seeds 5] [--repeats 3] [--quick]``

Times the experiment's IFP (the env recipe's PPO settings and env options, ``--seeds`` vmapped seeds, C physics) in
parts that add up to an update, all in one process so that they are compared side by side:

- **physics**: the bare batched C physics of an update's env steps (random actions, no policy);
- **learning**: an update's ``num_epochs`` SGD epochs alone (``Learner.learn``, compiled as the chunk is, on a
  rollout-sized batch of random data: SGD has no data-dependent branches). Timed apart rather than as the difference
  of chunks with ten epochs and with one, since the two runs' policies, and so their physics (contacts), differ;
- **acting**: the rest of the update: the policy's forward pass per step, the callback's host round trips, reward
  normalisation and GAE;
- **evaluation**: one curve evaluation and the final one (both splits), spread over the updates between them.

The learning's FLOP rate (forward and backward of the policy and value MLPs, 3x the forward's multiply-adds x 2)
is compared with the machine's float32 matmul rate at the update's own shape (seeds x minibatch rows through the
widest hidden layer): the floor a learner of these sizes can reach. That rate is timed beside the learner, call for
call, since this machine's speed drifts by 20-30 % over minutes; the peak at a large square size is printed too.
The learner is also timed as the process's MJX flag would compile it (fusion emitters off). Prints a table and
writes ``benchmarks/results/policy_stage.{json,md}``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs
from benchmarks.accelerator import time_chunk
from benchmarks.env_sps import BenchConfig, time_backend
from benchmarks.machine import machine_info
from experiments.cli import ArgumentParser, exit_status
from experiments.recipes import get_recipe
from talar_jax import runtime
from talar_jax.conditioning import GoalOneHotConditioner
from talar_jax.ppo import Minibatch, PPOConfig, derive, initial_state, make_evaluator, make_train

RESULTS_DIR = Path(__file__).parent / "results"


def _chunk_seconds(env_name: str, config: PPOConfig, repeats: int) -> float:
    """Seconds per update of the compiled chunk of ``config`` (``benchmarks.accelerator``'s timing, C physics):
    the median over ``repeats`` chunks after a warm-up one."""
    timed = time_chunk(env_name, "c", config, repeats + 1)
    return float(np.median(timed["chunk_s"][1:])) / config.updates_per_chunk


def _learning_seconds(
    config: PPOConfig, env, repeats: int, compiler_options: dict | None = None
) -> tuple[float, float]:
    """Seconds of one update's SGD, all seeds (see the module docstring), and the matmul rate at the update's shape
    measured beside it: each timed call of the SGD is followed by one of ``matmul_program``'s chain, so that the two
    share the machine's state (other tenants, clock) and their ratio is steady where absolute times are not. Medians
    of ``repeats`` pairs after a warm-up one. ``compiler_options``: the learner's (None) or others, to compare."""
    learner = make_train(config, env, GoalOneHotConditioner(env.num_goals))
    state = initial_state(learner)
    keys = jax.random.split(jax.random.PRNGKey(1), config.num_seeds)
    args = (state.params, state.opt_state, _random_rollout_batch(config, env, state), keys)
    options = learner.compiler_options if compiler_options is None else compiler_options
    learn = jax.jit(jax.vmap(learner.learn)).lower(*args).compile(compiler_options=options)
    reference, reference_flops = matmul_program(*update_shape(config), 2000)
    learn_s, reference_s = [], []
    for _ in range(repeats + 1):
        learn_s.append(_seconds(lambda: learn(*args)))
        reference_s.append(_seconds(reference))
    return float(np.median(learn_s[1:])), reference_flops / float(np.median(reference_s[1:]))


def _random_rollout_batch(config: PPOConfig, env, state) -> Minibatch:
    """A seed-stacked flat ``Minibatch`` of one rollout's shapes: random data, the env's real instructions."""
    seeds, size, spec = config.num_seeds, derive(config).env_steps_per_update, env.action_spec
    rng = np.random.default_rng(0)
    instruction = np.asarray(state.env.instruction)  # (seeds, num_envs, ...): real instructions, repeated
    instruction = np.concatenate([instruction] * -(-size // instruction.shape[1]), axis=1)[:, :size]
    if spec.kind == "continuous":
        action = rng.normal(size=(seeds, size, spec.size)).astype(np.float32)
    else:
        heads = spec.sizes if spec.kind == "multi_discrete" else (spec.size,)
        action = np.stack([rng.integers(0, n, (seeds, size)) for n in heads], -1).astype(np.int32)
        action = action[..., 0] if spec.kind == "discrete" else action
    normal = [rng.normal(size=(seeds, size)).astype(np.float32) for _ in range(3)]
    obs = rng.normal(size=(seeds, size, env.observation_size)).astype(np.float32)
    return Minibatch(obs, instruction, action, *normal)


def _seconds(call: Callable[[], Any]) -> float:
    start = time.perf_counter()
    jax.block_until_ready(call())
    return time.perf_counter() - start


def _evaluation_seconds(config: PPOConfig, env) -> tuple[float, float]:
    """Seconds of one curve evaluation and of the final one (both splits, every seed), untrained policy: every
    episode runs to the time limit, an evaluation's most expensive case."""
    learner = make_train(config, env, GoalOneHotConditioner(env.num_goals))
    params = initial_state(learner).params
    evaluate = make_evaluator(learner, ("train", "test"), env.num_goals, params)
    seconds = []
    for final in (False, True):
        evaluate(params, 0, final)  # the final evaluation's programs compile on first use
        start = time.perf_counter()
        evaluate(params, 1, final)
        seconds.append(time.perf_counter() - start)
    return seconds[0], seconds[1]


def _mlp_flops(sizes: list[int]) -> int:
    """Multiply-add FLOPs (2 per weight) of one sample's forward pass through dense layers of these widths."""
    return sum(2 * a * b for a, b in zip(sizes[:-1], sizes[1:], strict=False))


def learning_flops_per_update(config: PPOConfig, env) -> float:
    """FLOPs of one update's SGD (all seeds): forward + backward (3x forward) of the policy and value MLPs over
    ``num_epochs`` passes of the batch."""
    inputs = env.observation_size + env.num_goals
    hidden = list(config.hidden_sizes)
    action = env.action_spec.size
    per_sample = _mlp_flops([inputs, *hidden, action]) + _mlp_flops([inputs, *hidden, 1])
    return 3.0 * per_sample * derive(config).env_steps_per_update * config.num_epochs * config.num_seeds


def update_shape(config: PPOConfig) -> tuple[int, int]:
    """(rows, width) of the update's widest layer: all seeds' minibatch rows through the widest hidden layer."""
    return config.num_seeds * config.minibatch_size, max(config.hidden_sizes)


def matmul_program(rows: int, width: int, repeats: int) -> tuple[Callable[[], Any], float]:
    """A compiled chain of ``repeats`` float32 (rows, width) @ (width, width) products in one program (so that
    dispatch is not what is timed), as a call, and its FLOPs."""
    x = jnp.ones((rows, width), jnp.float32)
    w = jnp.full((width, width), 1.0 / width, jnp.float32)

    def chain(x, w):
        return jax.lax.fori_loop(0, repeats, lambda _, y: jnp.tanh(y @ w), x)

    run = jax.jit(chain).lower(x, w).compile()
    jax.block_until_ready(run(x, w))
    return (lambda: run(x, w)), 2.0 * rows * width * width * repeats


def matmul_rate(rows: int, width: int, repeats: int = 20) -> float:
    """Measured float32 FLOP/s of ``matmul_program``: the best of 5 calls."""
    call, flops = matmul_program(rows, width, repeats)
    return flops / min(_seconds(call) for _ in range(5))


def measure(env_name: str, seeds: int, repeats: int, quick: bool) -> dict:
    """One env's per-update parts, evaluation share and learner FLOP rate."""
    recipe = get_recipe(env_name)
    config = dataclasses.replace(recipe.ifp, num_seeds=seeds, updates_per_chunk=2)
    if quick:
        config = dataclasses.replace(config, num_envs=8, rollout_length=16, minibatch_size=32, num_epochs=2)
        config = dataclasses.replace(config, eval_episodes=4, final_eval_episodes=8)
    env = envs.make(env_name, physics="c", **recipe.env_options)
    sizes = derive(config)
    print(f"[{env_name}] chunks, and an update's SGD alone", flush=True)
    full = _chunk_seconds(env_name, config, repeats)
    learning, reference_rate = _learning_seconds(config, env, repeats)
    learning_process_flag, _ = _learning_seconds(config, env, repeats, compiler_options={})
    print(f"[{env_name}] bare physics and evaluation", flush=True)
    batch = config.num_envs * seeds
    bench = BenchConfig((), (), chunk_steps=config.rollout_length)
    physics_sps = time_backend(env_name, "c", batch, bench, 1.0 if quick else 5.0, recipe.env_options)["steps_per_s"]
    physics = sizes.env_steps_per_update * seeds / physics_sps
    curve_eval_s, final_eval_s = _evaluation_seconds(config, env)
    recipe_updates = derive(recipe.ifp).num_updates
    evaluations = -(-derive(recipe.ifp).num_chunks // recipe.ifp.eval_every_chunks)
    eval_per_update = (evaluations * curve_eval_s + final_eval_s) / recipe_updates
    flops = learning_flops_per_update(config, env)
    return {
        "env": env_name,
        "seeds": seeds,
        "config": {k: getattr(config, k) for k in ("num_envs", "rollout_length", "minibatch_size", "num_epochs")},
        "update_s": full,
        "physics_s": physics,
        "rollout_s": full - learning,
        "acting_overhead_s": full - learning - physics,
        "learning_s": learning,
        "learning_process_flag_s": learning_process_flag,
        "eval_curve_s": curve_eval_s,
        "eval_final_s": final_eval_s,
        "eval_per_update_s": eval_per_update,
        "eval_share": eval_per_update / (full + eval_per_update),
        "ratio_to_physics": (full + eval_per_update) / physics,
        "learning_flops_per_update": flops,
        "learning_flop_rate": flops / learning if learning > 0 else None,
        "matmul_rate_beside_learning": reference_rate,
        "learning_share_of_matmul_rate": flops / learning / reference_rate if learning > 0 else None,
    }


def markdown(rows: list[dict], rates: dict) -> str:
    lines = [
        "Seconds per PPO update (all seeds), C physics; evaluation spread over the updates of a run at the recipe's "
        "schedule (untrained policy: every episode to the time limit).",
        "",
        "| env | seeds | update | physics | acting (update - physics - learning) | learning (SGD) | evaluation | "
        "stage / physics | evaluation share | learning GFLOP/s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        rate = "-" if r["learning_flop_rate"] is None else f"{r['learning_flop_rate'] / 1e9:.2f}"
        lines.append(
            f"| {r['env']} | {r['seeds']} | {r['update_s']:.3f} | {r['physics_s']:.3f} | {r['acting_overhead_s']:.3f} "
            f"| {r['learning_s']:.3f} | {r['eval_per_update_s']:.3f} | {r['ratio_to_physics']:.2f} | "
            f"{100 * r['eval_share']:.1f} % | {rate} |"
        )
    lines += [
        "",
        f"Measured float32 matmul rate: {rates['peak'] / 1e9:.1f} GFLOP/s at {rates['peak_shape']} (the machine's "
        f"peak), {rates['update_shape_rate'] / 1e9:.2f} GFLOP/s at the update's shape {rates['update_shape']}.",
    ]
    for r in rows:
        if r["learning_flop_rate"]:
            lines.append(
                f"The {r['env']} learner runs at {100 * r['learning_share_of_matmul_rate']:.0f} % of the matmul rate "
                f"at its shape measured beside it ({r['matmul_rate_beside_learning'] / 1e9:.1f} GFLOP/s); compiled "
                f"under the process's MJX flag (fusion emitters off) it took {r['learning_process_flag_s']:.3f} s, "
                f"{r['learning_process_flag_s'] / r['learning_s']:.2f}x as long."
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    runtime.configure()
    parser = ArgumentParser(prog="python -m benchmarks.policy_stage", description=__doc__)
    parser.add_argument("--envs", nargs="+", default=["clevr", "kitchen"], help="envs to time (default: both)")
    parser.add_argument("--seeds", type=int, default=5, help="vmapped seeds, as the experiments run (default: 5)")
    parser.add_argument("--repeats", type=int, default=3, help="timed chunks per setting, median (default: 3)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check the command runs")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="folder for policy_stage.{json,md}")
    args = parser.parse_args()
    if args.seeds < 1 or args.repeats < 1:
        parser.error("--seeds and --repeats must be >= 1")
    for name in args.envs:
        get_recipe(name)
    rows = [measure(name, args.seeds, args.repeats, args.quick) for name in args.envs]
    shape = update_shape(dataclasses.replace(get_recipe(args.envs[0]).ifp, num_seeds=args.seeds))
    width = shape[1]
    rates = {
        "peak": matmul_rate(512 if args.quick else 1024, 512 if args.quick else 1024, 4),
        "peak_shape": "1024 x 1024" if not args.quick else "512 x 512",
        "update_shape_rate": matmul_rate(*shape, 200),
        "update_shape": f"{shape[0]} x {shape[1]} @ {width} x {width}",
    }
    table = markdown(rows, rates)
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"machine": machine_info(), "args": {**vars(args), "out": str(args.out)}, "rates": rates, "rows": rows}
    (args.out / "policy_stage.json").write_text(json.dumps(record, indent=2))
    (args.out / "policy_stage.md").write_text(table)
    print(table)


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
