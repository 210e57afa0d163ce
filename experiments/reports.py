"""What a finished run reports: its learning curves read back from the policy's metrics, the run's figures and
tables (``results.md``, ``summary.json``, ``curves.png``, ``tsne.png``) and the deployment strip."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import jax
import numpy as np

from experiments.config import ExperimentConfig, run_name
from experiments.methods import MethodSetup, method_label
from experiments.recipes import get_recipe
from talar_jax.checkpoint import write_json_atomic
from talar_jax.conditioning import SPLITS
from talar_jax.language import EmbeddingCache
from talar_jax.ppo import PPOConfig
from talar_jax.provenance import provenance
from talar_jax.report import (
    GoalCurves,
    LearningCurve,
    counted,
    plot_deployment_strip,
    plot_learning_curves,
    plot_tsne,
    results_table,
)
from talar_jax.stages import StageResult
from talar_jax.talar import TalarConfig
from talar_jax.task_language import TaskLanguageSpec


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


def final_success_per_seed_goal(ifp: StageResult) -> dict[str, list[list[float | None]]] | None:
    """split -> (seeds, goals) success of the last evaluation, or None for runs logged before it was recorded."""
    last = _eval_rows(ifp)[-1]
    if f"eval/{SPLITS[0]}/success_per_seed_goal" not in last:
        return None
    return {s: last[f"eval/{s}/success_per_seed_goal"] for s in SPLITS}


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f}"


def per_seed_goal_table(table: list[list[float | None]], names: list[str]) -> str:
    """Markdown table seed -> success (%) per goal, and the lowest seed's per goal: a seed that fails one goal
    shows here, where pooled and per-seed means average it away."""
    lines = ["| seed | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    lines += [f"| {seed} | " + " | ".join(map(_percent, row)) + " |" for seed, row in enumerate(table)]
    lowest = [min((v for v in column if v is not None), default=None) for column in zip(*table, strict=True)]
    lines.append("| lowest | " + " | ".join(map(_percent, lowest)) + " |")
    return "\n".join(lines) + "\n"


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


def _results_markdown(config, stages, setup, curve, per_goal, names) -> str:
    """``results.md``: the final success table, the TL's quality, stage times and (where the recipe asks) per goal."""
    title = f"{config.env} ({counted(config.seeds, 'seed')})"
    final = {s: curve.success[s][:, -1] for s in curve.success}
    table = results_table({method_label(config.method): final}, title=f"Final success rate, {title}")
    quality = setup.summary.get("tl_quality", {})
    table += "".join(
        f"\n- TL quality `{k}`: {np.mean(v):.3f} (per seed {np.round(v, 3).tolist()})" for k, v in quality.items()
    )
    table += "".join(f"\n- stage `{name}`: {stage.seconds:.0f} s" for name, stage in stages.items()) + "\n"
    if get_recipe(config.env).per_goal_report:
        table += "\n#### Final success per sub-task (pooled over seeds)\n\n"
        table += per_goal_table(per_goal, names)
        per_seed_goal = final_success_per_seed_goal(stages["ifp"])
        if per_seed_goal is not None:
            table += "\n#### Final success per seed and sub-task, training instructions (%)\n\n"
            table += per_seed_goal_table(per_seed_goal["train"], names)
    return table


def write_report(
    config: ExperimentConfig, stages: dict[str, StageResult], setup: MethodSetup, cache: EmbeddingCache
) -> dict[str, Any]:
    """Fig. 4-style curves, Fig. 5a-style t-SNE of the instruction encodings, a markdown table, ``summary.json``."""
    folder = config.out / run_name(config)
    label = method_label(config.method)
    curve = learning_curve(stages["ifp"])
    names = get_recipe(config.env).goal_names()
    per_goal_curves = goal_learning_curves(stages["ifp"], names) if get_recipe(config.env).per_goal_report else None
    title = f"{config.env} ({counted(config.seeds, 'seed')})"
    plot_learning_curves({label: curve}, folder / "curves.png", title=title, per_goal=per_goal_curves)
    encodings = setup.encodings[0] if setup.encodings is not None else trained_codes(folder)
    if encodings is not None:
        plot_tsne(
            encodings, cache.goal_ids, folder / "tsne.png", title=f"{label} encodings, {config.env}", label_names=names
        )
    per_goal = final_success_per_goal(stages["ifp"])
    (folder / "results.md").write_text(_results_markdown(config, stages, setup, curve, per_goal, names))
    summary = {
        "env": config.env,
        "method": config.method,
        "seeds": config.seeds,
        "ifp_env_steps_per_seed": int(curve.env_steps[-1]),
        "num_patterns": config.num_patterns,
        **provenance(),
        "final_success": {s: v[:, -1].tolist() for s, v in curve.success.items()},
        "final_success_per_goal": per_goal,
        "final_success_per_seed_goal": final_success_per_seed_goal(stages["ifp"]),
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
    from talar_jax.agent import AgentError

    try:
        agent = load_agent(folder, seed=seed, check_encoder=False)
    except AgentError:
        return None
    return agent.translate_features(agent.cache_features())


def load_agent(run_dir: str | Path, seed: int = 0, physics: str | None = None, check_encoder: bool = True):
    """``talar_jax.agent.Agent`` of a run folder; a folder finished before runs recorded ``encoding.json`` gets it
    written first, from its ``config.json`` and its method's registration (nothing is retrained)."""
    from talar_jax.agent import Agent, find_method_folder
    from talar_jax.encodings import ENCODING_FILE

    folder = find_method_folder(run_dir, prefer="talar")  # a comparison's folder: its TALAR run
    if not (folder / ENCODING_FILE).is_file() and (folder / "config.json").is_file():
        write_encoding_record(folder)
    return Agent(folder, seed=seed, physics=physics, check_encoder=check_encoder)


def write_encoding_record(folder: Path) -> None:
    """Writes a method folder's ``encoding.json`` from its ``config.json`` (for runs that predate the record)."""
    from experiments.methods import get_method
    from talar_jax.agent import read_config

    config = config_from_json(read_config(folder))  # resolved when it was written
    num_goals = len(get_recipe(config.env).goal_names())
    get_method(config.method).encoding(config, num_goals).write(folder)


def config_from_json(raw: dict[str, Any]) -> ExperimentConfig:
    """An ``ExperimentConfig`` from a run's ``config.json`` (the nested TL spec, PPO and TALAR settings rebuilt)."""

    def build(cls, values: dict[str, Any]):
        known = {f.name: f for f in dataclasses.fields(cls)}
        kwargs = {}
        for name, value in values.items():
            if name not in known:
                continue  # a field of an older version: it no longer changes anything
            kwargs[name] = tuple(value) if isinstance(value, list) else value
        return cls(**kwargs)

    talar = dict(raw["talar"])
    talar["spec"] = TaskLanguageSpec(**talar["spec"])
    fields = {**raw, "talar": build(TalarConfig, talar), "ifp": build(PPOConfig, raw["ifp"])}
    fields["out"] = Path(fields["out"]) if fields.get("out") else None
    fields["reuse_stages"] = tuple(Path(p) for p in fields.get("reuse_stages") or ())
    return build(ExperimentConfig, fields)


def write_deployment_strip(config: ExperimentConfig, folder: Path, cache: EmbeddingCache, frames: int = 5) -> str:
    """Paper Fig. 17/18: one learned episode of seed 0 per showcased goal, following the goal's first training
    instruction, a few frames each (``deployment.png``). Returns a line saying what was written or why not (One-hot
    cannot read a sentence; rendering needs an OpenGL backend)."""
    from envs.render import RenderError
    from talar_jax.agent import AgentError

    try:
        follower = load_agent(folder, seed=0, physics=config.physics, check_encoder=False)
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
    path = plot_deployment_strip(rows, folder / "deployment.png", title=f"{method_label(config.method)}, seed 0")
    return f"deployment strip: {path}"


def write_measures(out: Path, stem: str, params_bytes: bytes, record: dict, table: str, report: Path | None) -> None:
    """A fitted language model's files beside the agents (``<stem>.msgpack``, ``<stem>.json``) and its measures:
    printed, and written as markdown to ``report`` (when given) under a line naming the command and commit."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.msgpack").write_bytes(params_bytes)
    (out / f"{stem}.json").write_text(json.dumps(record, indent=1) + "\n")
    if report is not None:
        report.write_text(f"Made by `{record['command']}` at commit {record['commit']}.\n\n{table}")
    print(table)


def agent_command(args_class: type, body, doc: str | None):
    """``(run_command, main)`` of a command that loads an agent: its dataclass of options parsed by the project's
    parser, the runtime started first, and an ``AgentError`` (a damaged or unfinished run, a sentence the encoder
    cannot read) reported as bad input: one line, exit 2."""
    from experiments.cli import command, run_with_args
    from talar_jax import runtime
    from talar_jax.agent import AgentError

    run_command = run_with_args(args_class, body, doc, setup=runtime.start)
    return run_command, command(run_command, bad_input=(AgentError,))
