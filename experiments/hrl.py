"""Hierarchical RL with the task language as the high-level action space, against HAL (paper section 5.3, Fig. 6).

    python -m experiments.hrl --env clevr|kitchen --seeds 5 [--quick] [--out DIR] [--run-dir RUN]

The low level is one frozen TALAR instruction-following policy (``--ifp-seed`` of a finished ``experiments.clevr``
/ ``experiments.kitchen`` run: ``--run-dir``, default ``runs/<env>``, run there first when it is not finished). Every
high-level action is held for ``--hold`` (10) low-level steps; the reward of a low-level step is the number of goal
configurations holding at that step (CLEVR object arrangement: the 6 distinct constraints, ``--arrangement-reward
listed`` counts the paper's ten as listed; kitchen: the six sub-tasks, ``kitchen-all`` with
``all_tasks_reward='count'``). Methods, all trained by this project's PPO on the same low level:

- ``talar``: the high-level action is a task-language code (N_pn two-way and N_a ``arg_size``-way heads);
- ``hal``: the action is the index of a training instruction, translated to its TL code by the run's translator;
- ``flat``: PPO on the primitive actions with the same sparse reward (does the hierarchy help at all?).

Writes ``<out>/hrl.png`` (reward per episode against low-level env steps, mean +- std over seeds), ``results.md``
and ``summary.json``; each method's PPO is a cached, resumable stage ``<out>/<method>/``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

import envs
from experiments.cli import check_outputs, checked, command, parse
from experiments.config import default_config
from experiments.lock import hold
from experiments.pipeline import run
from experiments.recipes import HRLRecipe, get_recipe, recipe_names
from talar_jax import runtime
from talar_jax.checkpoint import write_json_atomic
from talar_jax.hrl import (
    HighLevelEnv,
    NoInstructionConditioner,
    SingleTaskWrapper,
    hal_code_table,
    talar_action_spec,
    task_language_code,
)
from talar_jax.ppo import PPOConfig, run_ppo
from talar_jax.report import counted
from talar_jax.stages import run_stage, stable_hash, to_jsonable
from talar_jax.task_language import TaskLanguageSpec

HRL_METHODS: tuple[str, ...] = ("talar", "hal", "flat")
METHOD_LABELS = {"talar": "TALAR (TL actions)", "hal": "HAL (NL instruction index)", "flat": "flat PPO"}


@dataclasses.dataclass(frozen=True)
class HRLArgs:
    """Hierarchical RL study (paper Fig. 6)."""

    env: str = "clevr"
    """clevr (object arrangement) or kitchen (all six sub-tasks)."""
    seeds: int = 5
    """High-level seeds per method (vmapped in one program)."""
    quick: bool = False
    """Tiny budgets everywhere (minutes): a smoke test of the whole study."""
    out: Path | None = None
    """Output folder (default runs/hrl-<env>)."""
    run_dir: Path | None = None
    """Finished TALAR run of the env whose IFP is the low level (default runs/<env>, or <out>/low-level with --quick;
    run there first when it is not finished)."""
    ifp_seed: int = 0
    """Which seed of that run's IFP (and translator) is the low level, shared by every method and seed."""
    methods: tuple[str, ...] = HRL_METHODS
    """Methods to train: talar, hal, flat."""
    hold: int = 10
    """Low-level steps per high-level action (the paper: 10)."""
    episode_length: int | None = None
    """High-level steps per episode (default: clevr 10, kitchen 28)."""
    env_steps: int | None = None
    """Low-level env steps per seed and method (default 1,000,000)."""
    arrangement_reward: str = "distinct"
    """CLEVR: count the 6 distinct arrangement constraints ('distinct') or the paper's ten as listed ('listed')."""
    physics: str | None = None
    """Physics backend (default: C on a CPU, MJX on an accelerator)."""
    seed: int = 0
    """Base seed of the high-level training."""
    progress: bool = True
    """Progress bars."""


def hrl_envs() -> tuple[str, ...]:
    """The envs whose recipe has a hierarchical RL set-up."""
    return tuple(name for name in recipe_names() if get_recipe(name).hrl is not None)


def hrl_recipe(env: str) -> HRLRecipe:
    """The hierarchical RL set-up of ``env``, or one clear error naming the envs that have one."""
    if env not in hrl_envs():
        raise ValueError(f"unknown env {env!r}; choose one of {', '.join(hrl_envs())}")
    return get_recipe(env).hrl


def resolve(args: HRLArgs) -> HRLArgs:
    """Validates (one ValueError per bad input) and fills the defaults."""
    defaults = hrl_recipe(args.env)
    unknown = [m for m in args.methods if m not in HRL_METHODS]
    if unknown or not args.methods:
        raise ValueError(f"unknown method(s) {unknown}; valid methods: {', '.join(HRL_METHODS)}")
    for name in ("seeds", "hold"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} must be >= 1, got {getattr(args, name)}")
    for name in ("episode_length", "env_steps"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.arrangement_reward not in ("distinct", "listed"):
        raise ValueError(f"unknown --arrangement-reward {args.arrangement_reward!r}; choose distinct or listed")
    physics = args.physics or envs.default_physics()
    if physics not in envs.PHYSICS_NAMES:
        raise ValueError(f"unknown physics {physics!r}; choose one of {', '.join(envs.PHYSICS_NAMES)}")
    out = args.out or Path(f"runs/hrl-{args.env}{'-quick' if args.quick else ''}")
    run_dir = args.run_dir or (out / "low-level" if args.quick else Path(f"runs/{args.env}"))
    episode_length = args.episode_length or (3 if args.quick else defaults.episode_length)
    env_steps = args.env_steps or (3 * 2048 * args.hold if args.quick else defaults.env_steps)
    return dataclasses.replace(
        args, out=out, run_dir=run_dir, physics=physics, episode_length=episode_length, env_steps=env_steps
    )


def low_level_run(args: HRLArgs) -> Path:
    """The TALAR run folder whose IFP is the low level; runs (or finishes) it when its IFP stage is missing."""
    folder = args.run_dir / "talar"
    if not (folder / "ifp" / "stage.json").is_file():
        print(f"[hrl] no finished TALAR run in {args.run_dir}: running `experiments.{args.env}` there first")
        config = default_config(args.env, seeds=max(args.ifp_seed + 1, 1 if args.quick else 5), quick=args.quick)
        run(dataclasses.replace(config, out=args.run_dir, physics=args.physics, progress=args.progress))
    return folder


def high_level_ppo(args: HRLArgs, steps: int, hidden: tuple[int, ...] = (64, 64)) -> PPOConfig:
    """PPO of the high-level policies (and of the flat baseline, with ``steps`` low-level steps per ``hold``)."""
    per_update = 32 * 8
    updates_per_chunk = max(1, min(10, steps // (per_update * 10)))
    chunks = max(1, steps // (per_update * updates_per_chunk))
    return PPOConfig(
        num_envs=32,
        rollout_length=8,
        total_env_steps=steps,
        num_epochs=4,
        minibatch_size=64,
        ent_coef=0.01,
        hidden_sizes=hidden,
        num_seeds=args.seeds,
        seed=args.seed,
        updates_per_chunk=updates_per_chunk,
        eval_every_chunks=max(1, chunks // 20),
        eval_episodes=64,
        eval_deterministic=False,
    )


def build(args: HRLArgs, method: str, run_folder: Path):
    """(env, PPO config, steps per PPO env step) of one method."""
    from experiments.reports import load_agent

    defaults = hrl_recipe(args.env)
    options = {**defaults.low_env_options, **{name: getattr(args, name) for name in defaults.args_options}}
    if method == "flat":
        low_env = SingleTaskWrapper(
            envs.make(defaults.low_env, physics=args.physics, episode_length=args.episode_length * args.hold, **options)
        )
        config = dataclasses.replace(high_level_ppo(args, args.env_steps), num_envs=64, rollout_length=16)
        return low_env, config, 1
    low_env = envs.make(defaults.low_env, physics=args.physics, **options)
    agent = load_agent(run_folder, seed=args.ifp_seed, physics=args.physics)
    if method == "talar":
        spec = TaskLanguageSpec(**agent.config["talar"]["spec"])
        action_spec, code_of_action = talar_action_spec(spec), lambda action: task_language_code(spec, action)
    else:
        action_spec, code_of_action = hal_code_table(agent.training_codes)
    env = HighLevelEnv(
        low_env,
        lambda obs, code, rng: agent.act(obs, code, rng),
        action_spec,
        code_of_action,
        hold=args.hold,
        episode_length=args.episode_length,
    )
    return env, high_level_ppo(args, args.env_steps // args.hold), args.hold


def train_method(args: HRLArgs, method: str, run_folder: Path, ifp_key: str):
    """One method's PPO as a cached, resumable stage."""
    env, config, steps_per_env_step = build(args, method, run_folder)
    key = stable_hash(
        "hrl", method, ifp_key, args.ifp_seed, args.hold, args.episode_length, args.arrangement_reward, config
    )

    def body(stage_dir: Path) -> dict[str, Any]:
        write_json_atomic(stage_dir / "config.json", to_jsonable({"args": args, "ppo": config}))
        result = run_ppo(
            config, env, NoInstructionConditioner(), stage_dir / "ppo", progress=args.progress, eval_splits=("train",)
        )
        return {"env_steps": result.env_steps * steps_per_env_step, "wall_s": result.wall_s}

    stage = run_stage(args.out, method, key, body)
    rows = [json.loads(line) for line in (stage.path / "ppo" / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "eval/train/episode_return_per_seed" in r]
    steps = np.array([r["train/env_steps"] * steps_per_env_step for r in rows], float)
    returns = np.array([r["eval/train/episode_return_per_seed"] for r in rows], float).T  # (seeds, T)
    return steps, returns


def area_under_curve(steps: np.ndarray, returns: np.ndarray) -> np.ndarray:
    """(seeds,) mean reward per episode over training: the trapezoid area under each seed's curve / step range."""
    if len(steps) < 2:
        return returns[:, -1]
    return np.trapezoid(returns, steps, axis=1) / (steps[-1] - steps[0])


def plot(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for method, (steps, returns) in curves.items():
        mean, std = returns.mean(0), returns.std(0)
        (line,) = ax.plot(steps, mean, label=METHOD_LABELS[method])
        ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
    ax.set_title(title)
    ax.set_xlabel("low-level env steps")
    ax.set_ylabel("reward per episode")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def hrl(args: HRLArgs) -> dict[str, Any]:
    """Runs the study (reusing finished stages) and writes the figure, the table and summary.json."""
    args = resolve(args)
    args.out.mkdir(parents=True, exist_ok=True)
    run_folder = low_level_run(args)
    ifp_key = json.loads((run_folder / "ifp" / "stage.json").read_text())["key"]
    curves = {method: train_method(args, method, run_folder, ifp_key) for method in args.methods}
    recipe = hrl_recipe(args.env)
    summary: dict[str, Any] = {
        "env": args.env,
        "low_env": recipe.low_env,
        "low_level_run": str(args.run_dir),
        "ifp_seed": args.ifp_seed,
        "hold": args.hold,
        "episode_length_high_level_steps": args.episode_length,
        "low_level_env_steps_per_seed": args.env_steps,
        "seeds": args.seeds,
        "arrangement_reward": args.arrangement_reward if "arrangement_reward" in recipe.args_options else None,
        "command": "python -m experiments.hrl " + " ".join(sys.argv[1:]),
        "methods": {},
    }
    seeds = counted(args.seeds, "seed")
    lines = [
        f"# Hierarchical RL on {args.env} ({recipe.low_env}), {seeds}, "
        f"{args.env_steps:,d} low-level env steps per seed{' (QUICK budget)' if args.quick else ''}",
        "",
        "| method | area under the curve (mean reward per episode over training) | final reward per episode |",
        "|---|---|---|",
    ]
    for method, (steps, returns) in curves.items():
        auc, final = area_under_curve(steps, returns), returns[:, -1]
        summary["methods"][method] = {
            "env_steps": steps.tolist(),
            "returns_per_seed": returns.tolist(),
            "auc_per_seed": auc.tolist(),
            "final_per_seed": final.tolist(),
        }
        lines.append(
            f"| {METHOD_LABELS[method]} | {auc.mean():.2f} ± {auc.std():.2f} | {final.mean():.2f} ± {final.std():.2f} |"
        )
    table = "\n".join(lines) + "\n"
    (args.out / "results.md").write_text(table)
    write_json_atomic(args.out / "summary.json", summary)
    plot(curves, args.out / "hrl.png", f"{args.env}: reward per episode (mean ± std over {seeds})")
    print(table)
    print(f"outputs in {args.out}: hrl.png, results.md, summary.json")
    return summary


def run_command(argv: list[str] | None = None) -> dict[str, Any]:
    """``python -m experiments.hrl`` for Python callers: the study's summary. Bad input, and a folder another command
    holds, raise ``experiments.cli.UsageError`` before any work."""
    runtime.start()
    args = parse(HRLArgs, argv, description=__doc__)
    resolved = checked(resolve, args)
    low_level = None if (resolved.run_dir / "talar" / "ifp" / "stage.json").is_file() else resolved.run_dir
    check_outputs((resolved.out, "--out", "folder"), (low_level, "--run-dir", "folder"))
    with hold(resolved.out):
        return hrl(args)


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
