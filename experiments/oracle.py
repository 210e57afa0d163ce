"""Collect an env's task dataset with a goal-conditioned oracle: a PPO policy or a scripted collector.

``python -m experiments.oracle --env clevr --out runs/oracle-clevr [--collector policy|scripted] [--quick]``

Collectors: ``policy`` trains a goal-conditioned PPO oracle (the paper's way); ``scripted`` (the default of both
envs) needs no training. On CLEVR it pushes only the goal's source ball, greedily towards the target point with
epsilon-random directions: the original collected CLEVR data in its ``collect`` action space (8 pushes of the
source ball), so s_i -> s_T shows which ball the instruction names, while a 40-action PPO oracle moves non-goal
balls in most episodes, which leaves the referential game with ambiguous state pairs. On FrankaKitchen it is
the IK-waypoint controller of ``envs/kitchen/scripted.py`` with Gaussian action noise: it covers all six
sub-tasks, where the PPO oracle here never learned the microwave (0 %), leaving it out of the dataset.

Writes under ``--out``: ``ppo/`` (policy collector: config.json, orbax checkpoints, metrics.jsonl,
progress.json; a killed run resumes from its last chunk), ``oracle.json`` (success per goal on train/test
instructions, env steps and wall-clock to the success target) and ``dataset/`` (``TaskDataset``: (s_i, a_i, s_T, L_N)
of successful episodes, L_N drawn from the goal's training instructions, with the config that made it).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

import envs
from experiments.cli import check_outputs, checked, command, parse
from experiments.config import QUICK_PPO_ENV_STEPS, quick_ppo
from experiments.lock import hold
from experiments.recipes import get_recipe
from talar_jax import runtime
from talar_jax.checkpoint import write_json_atomic
from talar_jax.conditioning import GoalOneHotConditioner, InstructionSampler
from talar_jax.dataset import TaskDataset, collect_task_dataset, policy_behaviour
from talar_jax.language.instructions import load_instructions
from talar_jax.logging import TerminalLogger
from talar_jax.networks import make_ppo_networks
from talar_jax.ppo import PPOConfig, run_ppo

COLLECTORS: tuple[str, ...] = ("policy", "scripted")


@dataclasses.dataclass(frozen=True)
class OracleArgs:
    """Oracle training and task-dataset collection."""

    env: str = "clevr"
    """Env name (one with goal ids and instructions: clevr or kitchen)."""
    out: Path = Path("runs/oracle")
    """Output directory (resumed when it already holds a run)."""
    collector: str | None = None
    """'policy' (train a goal-conditioned PPO oracle) or 'scripted' (clevr: greedy source-ball pushes in the
    original's collect action space; kitchen: the IK-waypoint controller with action noise); default: scripted."""
    physics: str = "c"
    """Physics backend: 'c' (MuJoCo C, fast on CPU) or 'mjx'."""
    seed: int = 0
    """PPO seed (and collection seed)."""
    quick: bool = False
    """Tiny budget for a smoke run (about a minute); the dataset then keeps failed episodes too (hindsight s_T)."""
    total_env_steps: int | None = None
    """PPO env steps (default per env)."""
    num_tuples: int | None = None
    """Task-dataset tuples (default per env: clevr 100k, kitchen 50k)."""
    target_success: float | None = None
    """Stop training once the mean success on training instructions reaches this (default per env)."""
    num_envs: int = 64
    """Parallel training envs."""
    rollout_length: int = 64
    """Steps per env per PPO update."""
    eval_episodes: int = 320
    """Evaluation episodes per instruction split."""
    eval_every_chunks: int = 2
    """Evaluate every this many chunks of 8 updates."""
    collect_envs: int = 512
    """Parallel envs while collecting the dataset."""
    progress: bool = True
    """Show progress bars."""


def _given(args: OracleArgs, name: str) -> bool:
    """Whether the option ``name`` was set to a value other than its default (which ``--quick`` then keeps)."""
    return getattr(args, name) != OracleArgs.__dataclass_fields__[name].default


def oracle_ppo_config(args: OracleArgs) -> PPOConfig:
    """The PPO config of an oracle run (defaults from Table 2; budget from the env recipe). ``--quick`` sets the quick
    budget but keeps an option given explicitly (a value other than its default)."""
    total = args.total_env_steps or get_recipe(args.env).oracle_env_steps
    if args.quick:
        config = quick_ppo(PPOConfig(seed=args.seed), args.total_env_steps or QUICK_PPO_ENV_STEPS)
        names = ("num_envs", "rollout_length", "eval_every_chunks", "eval_episodes")
        return dataclasses.replace(config, **{name: getattr(args, name) for name in names if _given(args, name)})
    return PPOConfig(
        num_envs=args.num_envs,
        rollout_length=args.rollout_length,
        total_env_steps=total,
        updates_per_chunk=8,
        eval_every_chunks=args.eval_every_chunks,
        eval_episodes=args.eval_episodes,
        seed=args.seed,
    )


def collector_of(args: OracleArgs) -> str:
    """The collector a run uses (``--collector`` or the env's default); raises on unknown names."""
    collector = args.collector or get_recipe(args.env).default_collector
    if collector not in COLLECTORS:
        raise ValueError(f"unknown collector {collector!r}; valid: {', '.join(COLLECTORS)}")
    return collector


def _train_policy(args: OracleArgs, env, conditioner) -> tuple[dict, Any]:
    """Trains (or resumes) the PPO oracle; returns its summary and one seed's parameters."""
    config = oracle_ppo_config(args)
    target = args.target_success if args.target_success is not None else get_recipe(args.env).oracle_target_success
    result = run_ppo(
        config,
        env,
        conditioner,
        args.out / "ppo",
        progress=args.progress,
        logger=TerminalLogger(
            ("eval/train/success", "eval/test/success", "train/success", "train/sps", "train/compile_s")
        ),
        target_success=target,
        stop_at_target=True,
    )
    summary = {
        "collector": "policy",
        "target_success": target,
        "target_reached": result.target_reached,
        "env_steps": result.env_steps,
        "train_wall_s": result.wall_s,
        "eval": result.last_eval,
        "success": float(result.last_eval["train"]["success"]),
        "ppo_config": dataclasses.asdict(config),
    }
    print(
        f"oracle: success {summary['success']:.3f} (train instructions) after "
        f"{result.env_steps} env steps, {result.wall_s:.0f} s; target {target} reached: {result.target_reached}"
    )
    return summary, jax.tree.map(lambda leaf: leaf[0], result.params)


def _collector_parts(args: OracleArgs, collector: str) -> tuple[dict[str, Any], Any, dict[str, Any]]:
    """(env options, behaviour, settings) of the collector: the recipe's scripted one, or ({}, None, {}) for a policy
    (the behaviour comes from the trained oracle)."""
    if collector != "scripted":
        return {}, None, {}
    recipe = get_recipe(args.env)
    if recipe.scripted_collector is None:
        raise ValueError(f"env {args.env!r} has no scripted collector; use --collector policy")
    return recipe.scripted_collector()


def _dataset_of_this_oracle(
    dataset_dir: Path, summary: dict[str, Any], num_tuples: int, collector: str
) -> TaskDataset | None:
    """The dataset ``dataset_dir`` holds when it is this oracle's (same env steps, size and collector), else None."""
    if not (dataset_dir / "task_dataset.npz").exists():
        return None
    existing = TaskDataset.load(dataset_dir)
    same_oracle = existing.config.get("env_steps") == summary["env_steps"]
    if same_oracle and len(existing) == num_tuples and existing.config.get("collector", "policy") == collector:
        return existing
    return None


def _collect(
    args: OracleArgs, env, conditioner, behaviour, seed_params, collector: str, summary: dict[str, Any], num_tuples: int
) -> TaskDataset:
    """The task dataset of the collector's behaviour (the trained policy's when the collector has none)."""
    instructions = load_instructions(args.env, "train")
    sampler = InstructionSampler({"train": (instructions.goal_cache_rows(), instructions.goal_sentence_counts)})
    if behaviour is None:
        hidden_sizes = oracle_ppo_config(args).hidden_sizes
        networks = make_ppo_networks(env.observation_size, conditioner.size, env.action_spec, hidden_sizes)
        behaviour = policy_behaviour(networks, seed_params, conditioner)
    return collect_task_dataset(
        env,
        behaviour,
        num_tuples,
        jax.random.PRNGKey(args.seed + 7),
        sampler,
        num_envs=16 if args.quick and not _given(args, "collect_envs") else args.collect_envs,
        progress=args.progress,
        successful_only=not args.quick,
        config={
            "env": args.env,
            "physics": args.physics,
            "env_steps": summary["env_steps"],
            "seed": args.seed,
            "collector": collector,
            "instruction_ids": "rows of load_instructions(env, 'all') / the embedding cache",
            "oracle_success": summary.get("success"),
        },
    )


def run(args: OracleArgs) -> float:
    """Trains (or resumes) the oracle, writes ``oracle.json`` and the dataset; returns the oracle's success."""
    recipe = get_recipe(args.env)
    collector = collector_of(args)
    options, behaviour, settings = _collector_parts(args, collector)
    env = envs.make(args.env, physics=args.physics, **options)
    conditioner = GoalOneHotConditioner(env.num_goals)
    if collector == "policy":
        summary, seed_params = _train_policy(args, env, conditioner)
    else:
        summary, seed_params = {"collector": "scripted", **settings, "env_steps": 0}, None

    summary = {"env": args.env, "physics": args.physics, **summary}
    write_json_atomic(args.out / "oracle.json", summary)

    num_tuples = args.num_tuples or (1_000 if args.quick else recipe.num_tuples)
    dataset_dir = args.out / "dataset"
    existing = _dataset_of_this_oracle(dataset_dir, summary, num_tuples, collector)
    if existing is not None:
        print(f"dataset: {dataset_dir} already holds {len(existing)} tuples of this oracle")
        return float(existing.config.get("oracle_success", summary.get("success", 0.0)))
    start = time.perf_counter()
    dataset = _collect(args, env, conditioner, behaviour, seed_params, collector, summary, num_tuples)
    collection = dataset.config["collection"]
    if collector == "scripted":  # the scripted collector's success is its collection success
        summary["success"] = dataset.config["oracle_success"] = collection["success_rate"]
    dataset.save(dataset_dir)
    print(
        f"dataset: {len(dataset)} tuples from {collection['kept_episodes']} successful episodes "
        f"({collection['success_rate']:.2f} success) in {time.perf_counter() - start:.0f} s -> {dataset_dir}"
    )
    summary["dataset"] = {
        "num_tuples": len(dataset),
        **collection,
        "goals": np.bincount(dataset.goal_ids, minlength=env.num_goals).tolist(),
    }
    write_json_atomic(args.out / "oracle.json", summary)
    return float(summary["success"])


def run_command(argv: list[str] | None = None) -> float:
    """``python -m experiments.oracle`` for Python callers: the oracle's success. A bad option or output folder, or a
    folder another command holds, raises ``experiments.cli.UsageError`` before any work."""
    runtime.start()
    args = parse(OracleArgs, argv, description=__doc__)
    checked(lambda: (get_recipe(args.env), collector_of(args), oracle_ppo_config(args)))
    check_outputs((args.out, "--out", "folder"))
    with hold(args.out):
        return run(args)


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
