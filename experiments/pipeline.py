"""The whole TALAR pipeline for one env and N seeds, as cached stages.

oracle + task dataset -> language cache -> the method's stages (for TALAR: referential game -> translator) ->
instruction-following policy (IFP) -> report. Each stage lives in ``<out>/<stage>/`` and is skipped when the hash of
its inputs (its key) is unchanged; a stage interrupted half-way runs again (PPO stages resume from their last chunk).
Seeds run vmapped in one compiled program per stage, sharded over ``jax.devices()``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import envs
from experiments.cli import check_outputs, checked, command, parse
from experiments.config import KEY_EXCLUDED_FIELDS, ExperimentConfig, default_config, make_env, resolve, run_name
from experiments.lock import hold
from experiments.methods import MethodContext, MethodSetup, get_method
from experiments.oracle import OracleArgs
from experiments.oracle import run as run_oracle
from experiments.reports import write_deployment_strip, write_report
from talar_jax import runtime
from talar_jax.checkpoint import write_json_atomic
from talar_jax.dataset import TaskDataset
from talar_jax.language import build_cache, load_encoder
from talar_jax.logging import MultiLogger, TensorBoardLogger, TerminalLogger
from talar_jax.ppo import run_ppo
from talar_jax.report import LANGUAGE_RECORD, REPORT_FILES
from talar_jax.stages import StageResult, finished_record, run_stage, stable_hash, to_jsonable
from talar_jax.talar import make_task_language_data


def check_inputs(config: ExperimentConfig) -> ExperimentConfig:
    """``resolve`` plus the checks that need the registry or read files (the method, the env options, the encoder
    folder), so a bad input stops the run before its first stage; returns the resolved config."""
    get_method(config.method)
    config = resolve(config)
    make_env(config)
    load_encoder(config.encoder)
    return config


def _oracle_args(config: ExperimentConfig, out: Path) -> OracleArgs:
    return OracleArgs(
        env=config.env,
        out=out,
        physics=config.physics,
        seed=config.seed,
        quick=config.quick,
        total_env_steps=config.oracle_env_steps,
        num_tuples=config.num_tuples,
        progress=config.progress,
    )


def stage_oracle_key(config: ExperimentConfig) -> str:
    """The oracle stage's key: the oracle's settings (not its folder or progress output) and the env's model."""
    args = dataclasses.replace(_oracle_args(config, Path()), progress=True)
    return stable_hash("oracle", args, envs.model_fingerprint(config.env))


def stage_oracle(config: ExperimentConfig) -> StageResult:
    """Goal-conditioned oracle and the task dataset (``experiments.oracle``), shared by every method."""
    key = stage_oracle_key(config)

    def body(stage_dir: Path) -> dict[str, Any]:
        success = run_oracle(_oracle_args(config, stage_dir))
        return {"oracle_train_success": success, "num_tuples": len(TaskDataset.load(stage_dir / "dataset"))}

    return run_stage(config.out, "oracle", key, body, reuse_from=config.reuse_stages)


def ifp_key(config: ExperimentConfig, method_key: str) -> str:
    """The IFP stage's key: the method's upstream key, every resolved field but ``KEY_EXCLUDED_FIELDS`` and the env's
    model (``envs.model_fingerprint``)."""
    fields = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name not in KEY_EXCLUDED_FIELDS}
    return stable_hash("ifp", method_key, fields, envs.model_fingerprint(config.env))


def stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    """Stage folder -> key of every stage after the oracle and language cache (the method's, then ``ifp``), from
    a resolved config: what decides whether a cached stage is reused."""
    keys = get_method(config.method).stage_keys(config, upstream_key, cache_key)
    return {**keys, "ifp": ifp_key(config, list(keys.values())[-1])}


def finished_summary(config: ExperimentConfig, keys: tuple[str, str] | None = None) -> dict[str, Any] | None:
    """The run summary of ``config`` (resolved) when its policy stage finished in ``config.out`` with exactly these
    settings (its recorded key is the one ``config`` gives: a run at another budget or recipe does not count), else
    None. ``keys``: (oracle stage key, language-cache key) when already known (several methods of one folder)."""
    if keys is None:
        keys = (stage_oracle_key(config), build_cache(config.env, config.encoder, progress=False).key)
    folder = config.out / run_name(config)
    record = finished_record(folder / "ifp")
    if record is None or record.get("key") != stage_keys(config, *keys)["ifp"]:
        return None
    path = folder / "summary.json"
    return json.loads(path.read_text()) if path.is_file() else None


def stage_ifp(config: ExperimentConfig, setup: MethodSetup, env) -> StageResult:
    """Algorithm 3: PPO on [observation, instruction encoding] (for TALAR: the frozen translator's TL)."""
    key = ifp_key(config, setup.key)

    def body(stage_dir: Path) -> dict[str, Any]:
        loggers = []
        if config.progress:
            loggers.append(TerminalLogger(("eval/train/success", "eval/test/success", "train/success", "train/sps")))
        if config.tensorboard:
            loggers.append(TensorBoardLogger(stage_dir / "ppo" / "tensorboard"))
        result = run_ppo(
            config.ifp,
            env,
            setup.conditioner,
            stage_dir / "ppo",
            progress=config.progress,
            logger=MultiLogger(*loggers) if loggers else None,
            initial_params=setup.initial_params,
        )
        return {
            "env_steps": result.env_steps,
            "wall_s": result.wall_s,
            **{f"{split}_success_per_seed": ev["success_per_seed"] for split, ev in result.last_eval.items()},
        }

    return run_stage(config.out, f"{run_name(config)}/ifp", key, body, reuse_from=config.reuse_stages)


def run(config: ExperimentConfig) -> dict[str, Any]:
    """Runs (or resumes) every stage of ``config.method`` and writes its report; returns the summary. Holds
    ``config.out``'s lock meanwhile (``experiments.lock``: ``FolderInUseError`` when another process holds it)."""
    config = check_inputs(config)
    with hold(config.out):
        return _run(config)


def _run(config: ExperimentConfig) -> dict[str, Any]:
    method = get_method(config.method)
    folder = config.out / run_name(config)
    folder.mkdir(parents=True, exist_ok=True)
    write_json_atomic(folder / "config.json", to_jsonable(config))
    start = time.perf_counter()
    stages: dict[str, StageResult] = {"oracle": stage_oracle(config)}
    cache = build_cache(config.env, config.encoder, progress=config.progress)
    language = {"encoder_name": cache.encoder_name, "weights_sha256": cache.weights_sha256, "cache_key": cache.key}
    write_json_atomic(folder / LANGUAGE_RECORD, language)
    method.encoding(config, cache.num_goals).write(folder)
    dataset = TaskDataset.load(stages["oracle"].path / "dataset")
    env = make_env(config)
    data = make_task_language_data(dataset, cache, config.sentence_readout)
    setup = method.setup(MethodContext(config, stages["oracle"].key, data, cache, dataset, env))
    stages.update(setup.stages)
    stages["ifp"] = stage_ifp(config, setup, env)
    summary = write_report(config, stages, setup, cache)
    if config.deployment_strip:
        print(write_deployment_strip(config, folder, cache))
    summary["wall_s_this_call"] = time.perf_counter() - start
    print((folder / "results.md").read_text())
    written = [name for name in REPORT_FILES if (folder / name).is_file()]
    print(f"outputs in {folder}: {', '.join(written)}")
    return summary


def checked_config(config: ExperimentConfig) -> ExperimentConfig:
    """``check_inputs(config)`` and its output folder (``--out``); bad input raises ``UsageError`` (one ``error:``
    line and status 2 on the command line)."""
    config = checked(check_inputs, config)
    check_outputs((config.out, "--out", "folder"))
    return config


def description(env: str) -> str:
    """The opening text of ``python -m experiments.<env> --help``."""
    return (
        f"The TALAR pipeline (or another --method's) on {env} for --seeds seeds: oracle and task dataset, language "
        "cache, the method's stages (for TALAR: referential game, translator), instruction-following policy, "
        "report. Each stage is cached in --out; a run started again resumes where it stopped.\n\n"
        f"The defaults shown are the {env} recipe's (experiments/recipes.py), which differs from the paper's "
        "Table 2 where the README says why. --quick is a small smoke run; an option given explicitly keeps its "
        "value under --quick."
    )


def run_command(env: str, argv: list[str] | None = None) -> dict[str, Any]:
    """``python -m experiments.<env>`` (``experiments.clevr`` / ``experiments.kitchen``) for Python callers:
    ``default_config(env)`` changed by the command line ``argv``, run holding the output folder's lock; returns the
    run's summary. A bad option or output folder, or a folder another command is running in, raises ``UsageError``
    before any stage runs."""
    runtime.start()
    config = parse(ExperimentConfig, argv, default=default_config(env), description=description(env))
    config = checked_config(config)
    with hold(config.out):
        return run(config)


def env_command(
    env: str,
) -> tuple[ExperimentConfig, Callable[[list[str] | None], dict[str, Any]], Callable[[list[str] | None], int]]:
    """What the module ``experiments.<env>`` holds: ``DEFAULT``, the env's default config; ``run_command(argv)``,
    the command for Python callers (``run_command`` above for ``env``: it returns the run's summary, bad input
    raises ``experiments.cli.UsageError``); and ``main(argv)``, the command line, which returns the exit status."""
    run_env = partial(run_command, env)
    return default_config(env), run_env, command(run_env, resumes=True)
