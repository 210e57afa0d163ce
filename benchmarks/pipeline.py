"""Wall-clock of TALAR's whole pipeline per stage and env, compile apart, beside the bare physics of its env steps.

``python -m benchmarks.pipeline [--envs clevr kitchen] [--seeds 5] [--ifp-chunks 4] [--physics-seconds 30] [--out DIR]``

Runs ``experiments.pipeline.run`` on each env's default configuration in a fresh folder: the oracle stage (task
dataset), the referential game and the translator at their full default budgets, and the first ``--ifp-chunks``
chunks of the instruction-following policy. The IFP's full-budget time is extrapolated from those chunks (their
evaluations included, compilation apart). Beside it: the bare physics of the same env steps, i.e. the batched C
backend stepping ``num_envs x seeds`` envs with random actions and no policy (``benchmarks.env_sps``' method), for
``--physics-seconds`` in all (30 by default), split into windows between the stages: before the referential game,
the translator and the policy stage, and after the policy stage. This machine's speed drifts by 20-30 % over
minutes; physics timed once, minutes away from the stages, moved the ratio by about 5 % between runs, and the
windows' spread is printed to show the drift. The ratio (RG + translator + IFP) / bare physics is what the pipeline
costs on top of simulating its experience; the target is 1.5. Prints a table and writes
``benchmarks/results/pipeline.{json,md}``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from unittest import mock

import numpy as np

import experiments.methods.talar
import experiments.methods.translation
import experiments.pipeline
from benchmarks.env_sps import BenchConfig, PhysicsClock
from benchmarks.machine import machine_info
from experiments.cli import ArgumentParser, exit_status
from experiments.config import default_config
from experiments.pipeline import run
from talar_jax import runtime
from talar_jax.ppo import derive

RESULTS_DIR = Path(__file__).parent / "results"
PHYSICS_SECONDS = 30.0  # how long the bare physics is timed by default, all windows together
# where the physics windows fall: before the referential game, the translator and the policy stage; after the policy
WINDOWS = ("talar/task_language", "talar/translator", "ifp", "end")


def _ifp_full_budget(metrics: list[dict], ppo, seeds: int) -> dict:
    """The policy stage at its full budget from the timed chunks' metrics: training at the steady rate (the first
    chunk left out) plus the full run's evaluations, the learning curve's at the measured cost of one and the dense
    final one (the timed run's last chunk). A curve evaluation's cost, when none ran, is the final one's scaled by
    episodes. The timed chunks come first in training, where every episode runs to the time limit: evaluation's worst
    case."""
    sizes = derive(ppo)
    steady = [row["train/sps"] for row in metrics[1:]] or [metrics[0]["train/sps"]]
    train_full_s = ppo.total_env_steps * seeds / float(np.mean(steady))
    final_eval_s = float(metrics[-1].get("eval/seconds", 0.0))
    evals = [row["eval/seconds"] for row in metrics[:-1] if "eval/seconds" in row]
    scale = ppo.eval_episodes / (ppo.final_eval_episodes or ppo.eval_episodes)
    eval_s = float(np.mean(evals)) if evals else final_eval_s * scale
    evals_full = -(-(ppo.total_env_steps // sizes.env_steps_per_chunk) // ppo.eval_every_chunks)
    eval_full_s = (evals_full - 1) * eval_s + final_eval_s
    return {
        "ifp_train_sps_steady": float(np.mean(steady)),
        "ifp_eval_seconds_each": eval_s,
        "ifp_evaluations_full": evals_full,
        "ifp_final_eval_seconds": final_eval_s,
        "ifp_eval_full_s_estimate": eval_full_s,
        "ifp_eval_share": eval_full_s / (train_full_s + eval_full_s),
        "ifp_full_s_estimate": train_full_s + eval_full_s,
    }


@contextlib.contextmanager
def physics_between_stages(clock: PhysicsClock, window_s: float) -> Iterator[list[dict]]:
    """While active, a window of the bare physics runs before each supervised stage and before and after the policy
    stage (``experiments.pipeline.run``'s own calls, wrapped where the methods look them up); yields the windows."""
    windows: list[dict] = []

    def window(label: str) -> None:
        steps, seconds = clock.time(window_s)
        windows.append({"before": label, "env_steps": steps, "seconds": seconds, "sps": steps / seconds})

    def timed_stage(real):
        def run_stage(run_dir, name, *args, **kwargs):
            window(name)
            return real(run_dir, name, *args, **kwargs)

        return run_stage

    def timed_ifp(config, setup, env):
        window("ifp")
        result = real_ifp(config, setup, env)
        window("end")
        return result

    real_ifp = experiments.pipeline.stage_ifp
    with contextlib.ExitStack() as stack:
        for module in (experiments.methods.talar, experiments.methods.translation):
            stack.enter_context(mock.patch.object(module, "run_stage", timed_stage(module.run_stage)))
        stack.enter_context(mock.patch.object(experiments.pipeline, "stage_ifp", timed_ifp))
        yield windows


def measure(env_name: str, seeds: int, ifp_chunks: int, out: Path, physics_seconds: float = PHYSICS_SECONDS) -> dict:
    """Runs the pipeline's stages for one env and returns the per-stage timings and the bare-physics comparison."""
    base = default_config(env_name, seeds=seeds)
    sizes = derive(base.ifp)
    full_steps = base.ifp.total_env_steps
    ran_steps = ifp_chunks * sizes.env_steps_per_chunk
    config = dataclasses.replace(base, out=out / env_name, ifp=dataclasses.replace(base.ifp, total_env_steps=ran_steps))
    batch = base.ifp.num_envs * seeds
    physics_config = BenchConfig((), (), chunk_steps=base.ifp.rollout_length)
    clock = PhysicsClock(env_name, "c", batch, physics_config, config.env_options)
    start = time.perf_counter()
    with physics_between_stages(clock, physics_seconds / len(WINDOWS)) as windows:
        summary = run(config)
    total_s = time.perf_counter() - start
    placed = tuple(w["before"] for w in windows)
    if placed != WINDOWS:
        raise SystemExit(f"benchmarks.pipeline: physics windows fell before {placed}, not {WINDOWS}")
    stage_seconds = summary["stage_seconds"]
    stages = {}
    for name, seconds in stage_seconds.items():
        folder = config.out / ("talar/ifp" if name == "ifp" else name)
        record = json.loads((folder / "stage.json").read_text())["summary"]
        stages[name] = {"seconds": seconds, "compile_s": record.get("compile_s")}
        if record.get("paraphrase_features_s") is not None:  # encoding the paraphrases (once per machine, cached)
            stages[name]["paraphrase_features_s"] = record["paraphrase_features_s"]
    metrics = [json.loads(line) for line in (config.out / "talar/ifp/ppo/metrics.jsonl").read_text().splitlines()]
    ifp_compile = next((row["train/compile_s"] for row in metrics if "train/compile_s" in row), 0.0)
    stages["ifp"]["compile_s"] = ifp_compile
    ifp = _ifp_full_budget(metrics, base.ifp, seeds)
    ifp_full_s = ifp["ifp_full_s_estimate"]
    rates, seconds = [w["sps"] for w in windows], sum(w["seconds"] for w in windows)
    physics = {
        "sps": sum(w["env_steps"] for w in windows) / seconds,
        "compile_s": clock.compile_s,
        "batch": batch,
        "seconds": seconds,
        "windows": windows,
        "window_sps_spread": max(rates) / min(rates) - 1.0,
    }
    physics_full_s = full_steps * seeds / physics["sps"]
    supervised_s = sum(
        stages[name]["seconds"] - (stages[name]["compile_s"] or 0.0)
        for name in ("talar/task_language", "talar/translator")
    )
    pipeline_full_s = supervised_s + ifp_full_s
    return {
        "env": env_name,
        "seeds": seeds,
        "ifp_env_steps_per_seed_full": full_steps,
        "ifp_env_steps_per_seed_timed": ran_steps,
        "stages": stages,
        "supervised_s": supervised_s,
        **ifp,
        "pipeline_full_s_estimate": pipeline_full_s,
        "bare_physics": physics,
        "bare_physics_full_s": physics_full_s,
        "ratio_to_bare_physics": pipeline_full_s / physics_full_s,
        "benchmark_wall_s": total_s,
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| env | stage | seconds | of which compile | of which encoding paraphrases (once per machine) |",
        "|---|---|---:|---:|---:|",
    ]
    for row in rows:
        for name, stage in row["stages"].items():
            compile_s = "-" if stage["compile_s"] is None else f"{stage['compile_s']:.0f}"
            encode_s = f"{stage['paraphrase_features_s']:.0f}" if "paraphrase_features_s" in stage else "-"
            timed = f" ({row['ifp_env_steps_per_seed_timed']:,} steps/seed timed)" if name == "ifp" else ""
            lines.append(f"| {row['env']} | {name}{timed} | {stage['seconds']:.0f} | {compile_s} | {encode_s} |")
    lines += [
        "",
        "| env | seeds | RG + translator s (no compile) | IFP s at full budget (est.) | of which evaluation | "
        "whole pipeline s | bare C physics s, same env steps | physics windows' spread | ratio |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row['env']} | {row['seeds']} | {row['supervised_s']:.0f} | {row['ifp_full_s_estimate']:.0f} | "
            f"{row['ifp_eval_full_s_estimate']:.0f} ({100 * row['ifp_eval_share']:.0f} %) | "
            f"{row['pipeline_full_s_estimate']:.0f} | {row['bare_physics_full_s']:.0f} | "
            f"{100 * row['bare_physics']['window_sps_spread']:.0f} % | {row['ratio_to_bare_physics']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    runtime.configure()  # with the compile cache: the stages' compile time is measured apart
    parser = ArgumentParser(prog="python -m benchmarks.pipeline", description=__doc__)
    parser.add_argument(
        "--envs", nargs="+", default=["clevr", "kitchen"], help="envs whose pipeline to time (default: clevr kitchen)"
    )
    parser.add_argument("--seeds", type=int, default=5, help="seeds of each run, vmapped (default: 5)")
    parser.add_argument("--ifp-chunks", type=int, default=4, help="IFP chunks timed (the rest is extrapolated)")
    parser.add_argument("--out", type=Path, default=None, help="run folder (default: a fresh temporary one)")
    parser.add_argument(
        "--physics-seconds",
        type=float,
        default=PHYSICS_SECONDS,
        help=f"seconds the bare physics is timed for (default: {PHYSICS_SECONDS:g})",
    )
    args = parser.parse_args()
    if args.seeds < 1 or args.ifp_chunks < 1 or args.physics_seconds <= 0:
        parser.error("--seeds and --ifp-chunks must be >= 1, and --physics-seconds > 0")
    out = args.out or Path(tempfile.mkdtemp(prefix="talar-pipeline-bench-"))
    rows = []
    for env_name in args.envs:
        rows.append(measure(env_name, args.seeds, args.ifp_chunks, out, args.physics_seconds))
        table = markdown(rows)
        machine = machine_info()
        RESULTS_DIR.mkdir(parents=True, exist_ok=True)
        (RESULTS_DIR / "pipeline.json").write_text(
            json.dumps({"machine": machine, "args": {**vars(args), "out": str(out)}, "rows": rows}, indent=2)
        )
        (RESULTS_DIR / "pipeline.md").write_text(table)
    print(table)


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
