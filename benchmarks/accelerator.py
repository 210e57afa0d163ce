"""What an accelerator buys: MJX env steps, PPO policy chunks with MJX or C physics, and the referential-game step.

``python -m benchmarks.accelerator [--quick] [--budget-s 420] [--out DIR] [--envs ...] [--sections ...]``

Runs on whatever JAX backend is present (a GPU when one is lent, the CPU otherwise) and measures, compile time
always reported apart from the steady-state rate:

- env steps per second of the MJX backend for each env at 1,024 / 4,096 / 16,384 envs (``benchmarks.env_sps``'
  method: a jitted, vmapped chunk of random-action steps of the training-wrapped env);
- one chunk of the instruction-following policy's PPO (the env recipe's settings, seeds vmapped, as the
  experiments run it) with MJX physics, everything on the device, and with MuJoCo's C physics on the host through
  the batched callback, learning on the device;
- one jitted, seed-vmapped referential-game step (TL generator + receiver update) at the recipe's batch size, on a
  synthetic task dataset of the real dataset's shapes (the real one needs the language encoder's weights).

Measurements run in that order. Each section stops starting new ones once its share of the wall-clock budget
(``--budget-s``) would be passed, and records what it skipped and why; an out-of-memory error is recorded as well
and ends that series' larger sizes. The results are rewritten after every measurement, so a run cut short by
``timeout`` keeps what it measured: ``benchmarks/results/accelerator.{md,json}`` (``--out DIR``: there; ``--quick``,
tiny sizes on the same code paths: a temporary folder unless ``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import jax
import mujoco
import numpy as np

import envs
from benchmarks.env_sps import BenchConfig, time_backend
from benchmarks.machine import machine_info
from envs.runtime import program_compiler_options
from experiments.cli import ArgumentParser, check_output_path, exit_status
from experiments.config import ExperimentConfig
from experiments.recipes import get_recipe
from talar_jax import runtime
from talar_jax.conditioning import GoalOneHotConditioner
from talar_jax.ppo import PPOConfig, derive, make_train
from talar_jax.talar import build_task_language_data, make_train_task_language, prepare_referential_data

RESULTS_DIR = Path(__file__).parent / "results"
ENVS = ("clevr", "kitchen")

# Each section may start a measurement until this share of --budget-s is used. The env-step rows stop first: they
# recompile for every batch size, and the policy chunks (the question an accelerator answers for this project) and
# the game steps need the rest.
SECTION_DEADLINE = {"env steps": 0.4, "PPO chunk": 0.85, "referential game": 1.0}


@dataclasses.dataclass(frozen=True)
class Sizes:
    """How much each section measures."""

    env_batches: tuple[int, ...]
    env_seconds: float
    """Steady-state timing window of each env-step row."""
    seeds: int
    chunk_calls: int
    """Chunks run per PPO row; with more than one the first is left out of the rate (one-off costs)."""
    rg_steps_per_call: int
    rg_seconds: float
    quick: bool


FULL = Sizes((1024, 4096, 16384), 2.0, ExperimentConfig.seeds, 2, 100, 2.0, quick=False)
# One env-step batch: every MJX batch size is a compile of its own, tens of seconds on a small CPU.
QUICK = Sizes((8,), 0.2, 2, 1, 5, 0.0, quick=True)


@dataclasses.dataclass(frozen=True)
class GameShapes:
    """The shapes of an env's referential-game data: its task dataset and language cache (all-MiniLM-L6-v2), read
    from the experiments' own once; the synthetic data the benchmark builds has them."""

    num_tuples: int
    sentences: int
    used_sentences: int
    """Training instructions the task dataset's tuples use."""
    tokens: tuple[int, int]
    """Fewest and most tokens of an instruction (the most: the game's ``max_tokens``)."""
    distinct_prefixes: int
    """Distinct prefix embeddings of the used instructions (decides the receiver's per-prefix layout)."""
    embedding_dim: int
    vocab_size: int


GAME_SHAPES = {
    "clevr": GameShapes(100_000, 1440, 720, (9, 17), 2331, 384, 32),
    "kitchen": GameShapes(50_000, 120, 60, (6, 25), 615, 384, 138),
}


def out_of_memory(error: BaseException) -> bool:
    """Whether ``error`` is XLA failing to allocate device memory."""
    text = str(error).lower()
    return any(words in text for words in ("resource_exhausted", "resource exhausted", "out of memory"))


class Runner:
    """Runs the measurements in order, skips what no longer fits the budget, and rewrites the results after each."""

    def __init__(self, budget_s: float, out: Path, header: dict):
        self.start = time.perf_counter()
        self.budget_s = budget_s
        self.out = out
        self.header = header
        self.rows: list[dict] = []
        self.last_wall: dict[str, float] = {}  # per section: the previous measurement's seconds, the next's estimate
        self.ended: dict[str, str] = {}  # series -> why its larger sizes are not measured

    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def skip_reason(self, section: str, series: str) -> str | None:
        if series in self.ended:
            return self.ended[series]
        deadline = SECTION_DEADLINE[section] * self.budget_s
        estimate = self.last_wall.get(section, 0.0)
        if self.elapsed() + estimate > deadline:
            previous = f", the previous measurement took {estimate:.0f} s" if estimate else ""
            return (
                f"wall-clock budget: {self.elapsed():.0f} s of --budget-s {self.budget_s:.0f} used{previous}; this "
                f"section starts none after {deadline:.0f} s"
            )
        return None

    def measure(self, row: dict, series: str, label: str, measurement: Callable[[], dict]) -> None:
        """Runs ``measurement`` (unless skipped) and records ``row`` with its result, or why it has none."""
        reason = self.skip_reason(row["section"], series)
        if reason is not None:
            print(f"[{self.elapsed():4.0f} s] skipped {label}: {reason}", flush=True)
            self.record({**row, "status": "skipped", "reason": reason})
            return
        print(f"[{self.elapsed():4.0f} s] measuring {label} ...", flush=True)
        started = time.perf_counter()
        try:
            result = {"status": "ok", **measurement()}
        except Exception as error:  # recorded, so that one failure leaves the other measurements their time
            kind = "out of memory" if out_of_memory(error) else "error"
            if kind == "error":
                traceback.print_exc()
            message = " ".join(str(error).split())[:300]  # one line: it goes into a table cell
            result = {"status": kind.replace(" ", "_"), "reason": f"{type(error).__name__}: {message}"}
            self.ended[series] = f"a smaller size of this series ended in {kind}"
        wall_s = time.perf_counter() - started
        self.last_wall[row["section"]] = wall_s
        self.record({**row, **result, "wall_s": wall_s})
        if result["status"] == "ok":
            print(f"        {result['steps_per_s']:,.0f} steps/s, compile {result['compile_s']:.1f} s", flush=True)
        else:
            print(f"        {result['status']}: {result['reason']}", flush=True)

    def record(self, row: dict) -> None:
        self.rows.append(row)
        self.out.mkdir(parents=True, exist_ok=True)
        results = {**self.header, "elapsed_s": self.elapsed(), "rows": self.rows}
        (self.out / "accelerator.json").write_text(json.dumps(results, indent=2) + "\n")
        (self.out / "accelerator.md").write_text(markdown(results))


# ------------------------------------------------------------------------------------------------
# The measurements
# ------------------------------------------------------------------------------------------------
def measure_env_steps(runner: Runner, env_names: list[str], sizes: Sizes) -> None:
    """MJX env steps/s per env and batch size; every env's smaller batches before any env's larger ones."""
    config = BenchConfig((), ())
    for batch in sizes.env_batches:
        for name in env_names:
            options = get_recipe(name).env_options
            runner.measure(
                {"section": "env steps", "env": name, "physics": "mjx", "size": f"{batch:,} envs", "batch": batch},
                f"env steps {name}",
                f"env steps: {name}, MJX, {batch:,} envs",
                lambda name=name, batch=batch, options=options: time_backend(
                    name, "mjx", batch, config, sizes.env_seconds, options
                ),
            )


def chunk_config(name: str, sizes: Sizes) -> PPOConfig:
    """The recipe's PPO for ``sizes.seeds`` seeds; with ``quick``, tiny rollouts and one update per chunk."""
    ppo = dataclasses.replace(get_recipe(name).ifp, num_seeds=sizes.seeds)
    if sizes.quick:
        ppo = dataclasses.replace(ppo, num_envs=4, rollout_length=8, minibatch_size=16, updates_per_chunk=1)
    return ppo


def time_chunk(name: str, physics: str, ppo: PPOConfig, calls: int) -> dict:
    """Env steps/s of the seed-vmapped, jitted PPO chunk (``talar_jax.ppo``'s program), compile apart."""
    env = envs.make(name, physics=physics, **get_recipe(name).env_options)
    learner = make_train(ppo, env, GoalOneHotConditioner(env.num_goals))
    keys = jax.random.split(jax.random.PRNGKey(ppo.seed), ppo.num_seeds)
    start = time.perf_counter()
    init = jax.jit(jax.vmap(learner.init)).lower(keys).compile()
    compile_s = time.perf_counter() - start
    state = jax.block_until_ready(init(keys))
    start = time.perf_counter()
    chunk = jax.jit(jax.vmap(learner.chunk)).lower(state).compile(compiler_options=learner.compiler_options)
    compile_s += time.perf_counter() - start
    seconds = []
    for _ in range(calls):
        start = time.perf_counter()
        state = jax.block_until_ready(chunk(state))[0]
        seconds.append(time.perf_counter() - start)
    env_steps = derive(ppo).env_steps_per_chunk * ppo.num_seeds
    steady = seconds[1:] or seconds  # the first call may pay one-off costs (device buffers, host threads)
    return {
        "steps_per_s": env_steps / float(np.mean(steady)),
        "compile_s": compile_s,
        "chunk_s": seconds,
        "env_steps_per_chunk": env_steps,
    }


def measure_chunks(runner: Runner, env_names: list[str], sizes: Sizes) -> None:
    """One PPO chunk per env with MJX physics (all on the device) and with C physics (stepped on the host)."""
    for name in env_names:
        ppo = chunk_config(name, sizes)
        size = f"{ppo.num_seeds} seeds x {ppo.num_envs} envs x {ppo.rollout_length} steps"
        size += f" x {ppo.updates_per_chunk} updates"
        for physics in ("mjx", "c"):
            runner.measure(
                {"section": "PPO chunk", "env": name, "physics": physics, "size": size, "num_envs": ppo.num_envs},
                f"PPO chunk {name} {physics}",
                f"PPO chunk: {name}, {physics} physics, {size}",
                lambda name=name, physics=physics, ppo=ppo: time_chunk(name, physics, ppo, sizes.chunk_calls),
            )


def synthetic_game_data(shapes: GameShapes, observation_size: int, seed: int = 0):
    """Random task-dataset and language arrays of ``shapes`` (``TaskLanguageData``): the step's cost depends on the
    shapes and on how many prefixes are distinct, not on the values."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(shapes.tokens[0], shapes.tokens[1] + 1, shapes.sentences)
    counts[0] = shapes.tokens[1]  # the longest instruction is among the used ones
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pool = rng.normal(size=(shapes.distinct_prefixes, shapes.embedding_dim)).astype(np.float32)
    prefixes = pool[np.arange(counts.sum()) % shapes.distinct_prefixes]  # repeats give the real distinct count
    sentence_ids = np.arange(shapes.num_tuples) % shapes.used_sentences
    return build_task_language_data(
        states=rng.normal(size=(shapes.num_tuples, observation_size)),
        final_states=rng.normal(size=(shapes.num_tuples, observation_size)),
        sentence_ids=rng.permutation(sentence_ids),
        sentence_embeddings=rng.normal(size=(shapes.sentences, shapes.embedding_dim)),
        prefix_embeddings=prefixes,
        prefix_next_token=rng.integers(0, shapes.vocab_size, len(prefixes)),
        sentence_prefix_start=starts,
        sentence_prefix_count=counts,
    )


def time_referential_game(name: str, sizes: Sizes) -> dict:
    """Gradient steps/s of the recipe's referential game (generator + receiver), seeds vmapped, compile apart."""
    config, shapes = get_recipe(name).talar, GAME_SHAPES[name]
    data = prepare_referential_data(config, synthetic_game_data(shapes, envs.make(name).observation_size))
    fit = make_train_task_language(config, shapes.vocab_size, shapes.tokens[1])
    keys = jax.random.split(jax.random.PRNGKey(0), sizes.seeds)
    start = time.perf_counter()
    init = jax.jit(jax.vmap(fit.init, in_axes=(0, None))).lower(keys, data).compile()
    compile_s = time.perf_counter() - start
    state = jax.block_until_ready(init(keys, data))
    start = time.perf_counter()
    steps = sizes.rg_steps_per_call
    run = jax.jit(jax.vmap(lambda s, d: fit.run(s, d, steps=steps), in_axes=(0, None))).lower(state, data)
    run = run.compile(compiler_options=program_compiler_options(steps_mjx=False))
    compile_s += time.perf_counter() - start
    state = jax.block_until_ready(run(state, data))[0]  # warm-up
    calls, start = 0, time.perf_counter()
    while calls == 0 or time.perf_counter() - start < sizes.rg_seconds:
        state = jax.block_until_ready(run(state, data))[0]
        calls += 1
    steps_per_s = calls * steps / (time.perf_counter() - start)
    return {
        "steps_per_s": steps_per_s,
        "ms_per_step": 1000 / steps_per_s,
        "compile_s": compile_s,
        "tuples_per_s": steps_per_s * config.referential_batch_size * sizes.seeds,
        "steps_per_call": steps,
        "data": "synthetic, real shapes",
    }


def measure_referential_game(runner: Runner, env_names: list[str], sizes: Sizes) -> None:
    """One referential-game row per env, at the recipe's batch size."""
    for name in env_names:
        batch = get_recipe(name).talar.referential_batch_size
        size = f"{sizes.seeds} seeds x {batch} tuples"
        runner.measure(
            {"section": "referential game", "env": name, "physics": "-", "size": size, "batch": batch},
            f"referential game {name}",
            f"referential-game step: {name}, {size}",
            lambda name=name: time_referential_game(name, sizes),
        )


SECTIONS = {"env-steps": measure_env_steps, "chunks": measure_chunks, "game": measure_referential_game}


# ------------------------------------------------------------------------------------------------
# Report and command line
# ------------------------------------------------------------------------------------------------
def markdown(results: dict) -> str:
    versions, quick = results["versions"], results["quick"]
    cache = " (with the compile cache: compile seconds may be cache loads)" if quick else ""
    lines = [
        "# Accelerator benchmark",
        "",
        f"Device: {results['device']} (JAX backend {results['machine']['jax_backend']}), JAX {versions['jax']}, "
        f"MuJoCo {versions['mujoco']}. Quick run: {'yes' + cache if quick else 'no'}. Wall-clock budget "
        f"{results['budget_s']:.0f} s, {results['elapsed_s']:.0f} s used. Env steps and PPO chunks: env steps per "
        "second; referential game: gradient steps per second (every seed's). Compilation apart.",
        "",
        "| measured | env | physics | size | steps/s | compile s | note |",
        "|---|---|---|---|---:|---:|---|",
    ]
    for row in results["rows"]:
        if row["status"] == "ok":
            rate, compile_s = f"{row['steps_per_s']:,.0f}", f"{row['compile_s']:.1f}"
            note = f"{row['ms_per_step']:.2f} ms per step, synthetic data" if "ms_per_step" in row else ""
        else:
            rate, compile_s, note = "-", "-", f"{row['status'].replace('_', ' ')}: {row['reason']}".replace("|", "/")
        lines.append(
            f"| {row['section']} | {row['env']} | {row['physics']} | {row['size']} | {rate} | {compile_s} | {note} |"
        )
    return "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = ArgumentParser(prog="python -m benchmarks.accelerator", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="tiny sizes on the same code paths (a smoke test)")
    parser.add_argument(
        "--budget-s", type=float, default=420.0, help="wall-clock seconds the measurements may start in (default: 420)"
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="results folder (default: benchmarks/results; --quick: a temporary one)"
    )
    parser.add_argument("--envs", nargs="+", choices=ENVS, default=list(ENVS), help="envs to measure (default: both)")
    parser.add_argument(
        "--sections",
        nargs="+",
        choices=list(SECTIONS),
        default=list(SECTIONS),
        help="what to measure, e.g. only the chunks when a rerun has little GPU time left (default: all, in order)",
    )
    parser.add_argument(
        "--batches", type=int, nargs="+", default=None, help="env-step batch sizes (default: 1024 4096 16384)"
    )
    parser.add_argument("--seeds", type=int, default=None, help="seeds vmapped in the chunks and game (default: 5)")
    args = parser.parse_args(argv)
    if args.budget_s <= 0:
        parser.error(f"--budget-s must be > 0, got {args.budget_s:g}")
    if args.batches is not None and min(args.batches) < 1:
        parser.error(f"--batches must all be >= 1, got {' '.join(map(str, args.batches))}")
    if args.seeds is not None and args.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {args.seeds}")
    check_output_path(args.out, "--out")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    # Compile time is part of what the full run reports: no persistent cache. The quick run is a smoke test of the
    # code paths, and with the cache a rerun loads its MJX programs instead of compiling them again (the C-physics
    # chunks call back into Python, which JAX never caches).
    runtime.configure(compile_cache=args.quick)
    sizes = dataclasses.replace(
        QUICK if args.quick else FULL,
        **({"env_batches": tuple(args.batches)} if args.batches else {}),
        **({"seeds": args.seeds} if args.seeds else {}),
    )
    out = args.out or (Path(tempfile.mkdtemp(prefix="talar-accelerator-")) if args.quick else RESULTS_DIR)
    header = {
        "device": jax.devices()[0].device_kind,
        "machine": machine_info(),
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
        "quick": args.quick,
        "budget_s": args.budget_s,
        "sizes": dataclasses.asdict(sizes),
    }
    print(f"device: {header['device']} ({jax.default_backend()}); results go to {out}", flush=True)
    if jax.default_backend() == "cpu" and not args.quick:  # a GPU machine whose JAX lacks its CUDA build lands here
        print("note: JAX sees no accelerator, so these are CPU numbers (a GPU needs JAX's CUDA build)", flush=True)
    runner = Runner(args.budget_s, out, header)
    for section in args.sections:
        SECTIONS[section](runner, args.envs, sizes)
    print("\n" + markdown({**header, "elapsed_s": runner.elapsed(), "rows": runner.rows}))
    print(f"wrote {out / 'accelerator.md'} and {out / 'accelerator.json'}", flush=True)
    failed = [row for row in runner.rows if row["status"] == "error"]
    if failed:
        raise SystemExit(f"{len(failed)} measurement(s) failed (see the traceback above and the table)")


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
