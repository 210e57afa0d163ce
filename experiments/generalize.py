"""Your own phrasings, evaluated like a run's own evaluation: TL agreement and success per seed.

``python -m experiments.generalize RUN_DIR --instructions FILE.json [--episodes N] [--json OUT]``

FILE holds ``{"kitchen": {"<sub-task>": ["sentence", ...]}}`` and/or ``{"clevr_patterns": ["... {subject} ...
{relation} ... {object} ..."]}`` (patterns filled for all 80 goals as the project fills its own); the run reads
its own env's entry. For every seed of the run, and for the run's training and test instructions beside yours,
it prints TL agreement (the fraction of sentences whose code equals their goal's training code) and success on
``--episodes`` episodes (a goal uniform over the set's goals, one of its sentences uniform); the three sets share the
episodes' goals and random keys, so their success rates are paired.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np
import tyro

from experiments.cli import output_path_problem
from experiments.instruct import agent_command
from experiments.reports import load_agent
from talar_jax import runtime
from talar_jax.agent import Agent, AgentError, find_method_folder
from talar_jax.language import load_instructions, load_user_instructions
from talar_jax.report import counted


@dataclasses.dataclass(frozen=True)
class GeneralizeArgs:
    run_dir: tyro.conf.Positional[Path]
    """A finished run folder (``runs/clevr`` or a method folder such as ``runs/clevr/talar``)."""
    instructions: Path
    """JSON file of your phrasings (format above)."""
    episodes: int = 200
    """Episodes per seed and instruction set."""
    json: Path | None = None
    """Also write the results here."""
    rng_seed: int = 0
    """Seed of the episodes' randomness."""


def instruction_sets(agent: Agent, instructions: Path) -> dict[str, tuple[np.ndarray, np.ndarray, list[str]]]:
    """name -> (features (S, F), goal ids (S,), sentences) of the run's train and test sets and the user's."""
    cache, features = agent.cache, agent.cache_features()
    sets = {}
    for split in ("train", "test"):
        patterns = agent.config.get("num_patterns") if split == "train" else None
        rows = load_instructions(agent.env_name, split, patterns).sentence_ids
        sets[split] = (features[rows], cache.goal_ids[rows], [cache.sentences[r] for r in rows])
    sentences, goals = load_user_instructions(instructions, agent.env_name)
    sets["yours"] = (agent.encode(sentences), goals, sentences)
    return sets


def evaluate_seed(agent: Agent, sets: dict, episodes: int, rng_seed: int) -> dict[str, dict[str, float]]:
    """TL agreement and paired-episode success of every instruction set for one seed: every set plays the same
    goals with the same episode keys (the goals the user's sentences cover)."""
    choice = np.random.default_rng(rng_seed)
    goal_pool = np.array(sorted(set(sets["yours"][1].tolist())))
    goals = goal_pool[choice.integers(0, len(goal_pool), episodes)]
    rng_episodes = jax.random.key(rng_seed)
    out = {}
    for name, (features, sentence_goals, _) in sets.items():
        codes = agent.translate_features(features)
        agree = [np.array_equal(code.round(3), agent.goal_code(goal)) for code, goal in zip(codes, sentence_goals)]
        rows = np.array([choice.choice(np.flatnonzero(sentence_goals == goal)) for goal in goals])
        success = agent.success_rate(codes[rows], goals, rng_episodes)
        out[name] = {"tl_agreement": float(np.mean(agree)), "success": float(np.mean(success)), "sentences": len(codes)}
    return out


def report(per_seed: list[dict[str, dict[str, float]]]) -> str:
    names = list(per_seed[0])
    lines = ["| seed | " + " | ".join(f"{n}: TL agreement | {n}: success" for n in names) + " |"]
    lines.append("|---|" + "---:|---:|" * len(names))
    for seed, row in enumerate(per_seed):
        cells = [f"{100 * row[n]['tl_agreement']:.1f} | {100 * row[n]['success']:.1f}" for n in names]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    cells = []
    for n in names:
        for metric in ("tl_agreement", "success"):
            values = 100 * np.array([row[n][metric] for row in per_seed])
            cells.append(f"{values.mean():.1f} ± {values.std():.1f}")
    lines.append("| mean ± std | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def seed_line(seed: int, row: dict[str, dict]) -> str:
    """One seed's TL agreement and success per instruction set, in percent."""
    parts = [
        f"{name} TL agreement {100 * values['tl_agreement']:.1f} %, success {100 * values['success']:.1f} %"
        for name, values in row.items()
    ]
    return f"seed {seed}: " + "; ".join(parts)


def generalize(args: GeneralizeArgs) -> dict:
    if args.episodes < 1:
        raise AgentError(f"--episodes must be >= 1, got {args.episodes}")
    if args.json is not None and output_path_problem(args.json, "file"):
        raise AgentError(f"--json: {output_path_problem(args.json, 'file')}")
    folder = find_method_folder(args.run_dir, prefer="talar")
    seeds = int(json.loads((folder / "config.json").read_text())["seeds"])
    per_seed, sizes = [], {}
    for seed in range(seeds):
        agent = load_agent(folder, seed=seed)
        if seed == 0:
            try:
                sets = instruction_sets(agent, args.instructions)
            except (ValueError, FileNotFoundError) as error:
                raise AgentError(str(error)) from None
            sizes = {name: len(s[2]) for name, s in sets.items()}
            counts = ", ".join(f"{name} {count}" for name, count in sizes.items())
            print(f"run: {folder} ({agent.method}, {agent.env_name}, {counted(seeds, 'seed')}); sentences: {counts}")
        per_seed.append(evaluate_seed(agent, sets, args.episodes, args.rng_seed))
        print(seed_line(seed, per_seed[-1]), flush=True)
    table = report(per_seed)
    print(table)
    result = {"run": str(folder), "episodes_per_seed": args.episodes, "sentences": sizes, "per_seed": per_seed}
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return result


def main(argv: list[str] | None = None) -> dict:
    runtime.start()
    return agent_command(GeneralizeArgs, generalize, argv, __doc__)


if __name__ == "__main__":
    main()
