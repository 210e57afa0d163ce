"""Env throughput: MJX and MuJoCo-C backends at several batch sizes vs the original envs' stepping style.

``python -m benchmarks.env_sps [--env clevr] [--quick]`` prints a table and writes
``benchmarks/results/env_sps_<env>.json``. Each JAX row times a jitted, vmapped chunk of ``chunk_steps`` random-action
steps of the training-wrapped env (time limit + auto-reset, so a fresh reset is computed every step) after a
separately reported compile (jit of reset + the scanned chunk); steady state = repeated chunks for ``min_seconds``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import jax
import mujoco
import numpy as np

import envs
from benchmarks.original_style import original_steps_per_second
from experiments.cli import ArgumentParser, exit_status
from talar_jax import runtime

RESULTS_DIR = Path(__file__).parent / "results"


def random_actions(spec: envs.ActionSpec, key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """Uniform random actions of ``spec`` with leading ``shape``."""
    if spec.kind == "discrete":
        return jax.random.randint(key, shape, 0, spec.size)
    return jax.random.uniform(key, shape + (spec.size,), minval=spec.low, maxval=spec.high)


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """What to measure for one env."""

    mjx_batches: tuple[int, ...]
    c_batches: tuple[int, ...]
    chunk_steps: int = 10
    """Env steps per jitted call (a lax.scan)."""
    min_seconds: float = 3.0
    """Steady-state timing window per row."""
    original_steps: int = 600
    """Env steps of the original-style loop."""


BENCH_CONFIGS: dict[str, BenchConfig] = {
    "clevr": BenchConfig(mjx_batches=(1, 64, 256, 1024), c_batches=(1, 64, 256)),
    "kitchen": BenchConfig(mjx_batches=(1, 16, 64, 256), c_batches=(1, 16, 64, 256), original_steps=200),
}


class PhysicsClock:
    """``batch`` training-wrapped envs stepped with random actions in jitted chunks of ``config.chunk_steps`` (compiled
    and warmed up once), timed in as many windows as asked: a benchmark can interleave them with the work it compares
    against, so that the machine's drift falls on both sides."""

    def __init__(
        self, name: str, physics: str, batch: int, config: BenchConfig, env_options: dict | None = None
    ) -> None:
        env = envs.wrap_for_training(envs.make(name, physics=physics, **(env_options or {})))

        def init(key):
            return jax.vmap(env.reset)(jax.random.split(key, batch))

        def chunk(state, key):
            actions = random_actions(env.action_spec, key, (config.chunk_steps, batch))
            state, _ = jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), state, actions)
            return state

        key = jax.random.key(0)
        start = time.perf_counter()
        init_jit = jax.jit(init).lower(key).compile()
        self._state = init_jit(key)
        self._chunk = jax.jit(chunk).lower(self._state, key).compile()
        self.compile_s = time.perf_counter() - start
        self._state = jax.block_until_ready(self._chunk(self._state, jax.random.key(1)))  # warm-up
        self._calls = 0
        self.steps_per_call = config.chunk_steps * batch

    def time(self, min_seconds: float) -> tuple[int, float]:
        """Steps chunks for at least ``min_seconds`` (one at least); returns (env steps, seconds)."""
        calls, start = 0, time.perf_counter()
        while calls == 0 or time.perf_counter() - start < min_seconds:
            self._state = self._chunk(self._state, jax.random.key(2 + self._calls))
            jax.block_until_ready(self._state)
            calls += 1
            self._calls += 1
        return calls * self.steps_per_call, time.perf_counter() - start


def time_backend(
    name: str, physics: str, batch: int, config: BenchConfig, min_seconds: float, env_options: dict | None = None
) -> dict:
    """Steady-state env steps/s of ``batch`` training-wrapped envs with random actions (compile time apart)."""
    clock = PhysicsClock(name, physics, batch, config, env_options)
    steps, elapsed = clock.time(min_seconds)
    return {
        "backend": physics,
        "batch": batch,
        "steps_per_s": steps / elapsed,
        "compile_s": clock.compile_s,
        "timed_env_steps": steps,
    }


def run(name: str, quick: bool = False) -> dict:
    """Measures every row for env ``name``; returns the JSON-able results."""
    if name not in BENCH_CONFIGS:
        raise ValueError(f"no benchmark config for {name!r}; choose one of {', '.join(BENCH_CONFIGS)}")
    config = BENCH_CONFIGS[name]
    min_seconds = 0.5 if quick else config.min_seconds
    original_steps = max(50, config.original_steps // 4) if quick else config.original_steps
    rows = []
    original_steps_per_second(name, max(10, original_steps // 10))  # warm-up (model load, caches)
    original_before = original_steps_per_second(name, original_steps)
    print(f"  measured original style: {original_before:.0f} steps/s", flush=True)
    for physics, batches in (("c", config.c_batches), ("mjx", config.mjx_batches)):
        for batch in batches[:2] if quick else batches:
            rows.append(time_backend(name, physics, batch, config, min_seconds))
            print(f"  measured {physics} batch {batch}: {rows[-1]['steps_per_s']:.0f} steps/s", flush=True)
    # the machine is shared: the baseline is timed before and after the JAX rows, ratios use the mean
    original_after = original_steps_per_second(name, original_steps)
    original = (original_before + original_after) / 2
    rows.insert(
        0,
        {
            "backend": "original-style",
            "batch": 1,
            "steps_per_s": original,
            "compile_s": 0.0,
            "steps_per_s_before": original_before,
            "steps_per_s_after": original_after,
        },
    )
    for row in rows:
        row["ratio_to_original"] = row["steps_per_s"] / original
    return {
        "env": name,
        "quick": quick,
        "config": dataclasses.asdict(config),
        "machine": {"processor": platform.processor(), "cpu_count": os.cpu_count()},
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
        "rows": rows,
    }


def print_table(results: dict) -> None:
    print(f"\nenv steps/s for {results['env']} (compile = jit of reset + scanned chunk, reported apart)")
    print(f"{'backend':<16}{'batch':>7}{'steps/s':>12}{'x original':>12}{'compile s':>11}")
    for row in results["rows"]:
        print(
            f"{row['backend']:<16}{row['batch']:>7}{row['steps_per_s']:>12.0f}"
            f"{row['ratio_to_original']:>12.2f}{row['compile_s']:>11.1f}"
        )


def main() -> None:
    runtime.configure(compile_cache=False)  # compile time is part of what benchmarks report
    parser = ArgumentParser(prog="python -m benchmarks.env_sps", description=__doc__)
    parser.add_argument("--env", default="clevr", choices=sorted(BENCH_CONFIGS), help="env to time (default: clevr)")
    parser.add_argument("--quick", action="store_true", help="short timing windows, first two batch sizes only")
    args = parser.parse_args()
    results = run(args.env, args.quick)
    print_table(results)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"env_sps_{args.env}{'_quick' if args.quick else ''}.json"
    path.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    raise SystemExit(exit_status(main))
