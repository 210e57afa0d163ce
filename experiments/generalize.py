"""Your own phrasings, evaluated like a run's own evaluation: TL agreement and success per seed.

``python -m experiments.generalize RUN_DIR --instructions FILE.json [--episodes N] [--json OUT]``

FILE holds ``{"kitchen": {"<sub-task>": ["sentence", ...]}}`` and/or ``{"clevr_patterns": ["... {subject} ...
{relation} ... {object} ..."]}`` (patterns filled for all 80 goals as the project fills its own); the run reads
its own env's entry. For every seed of the run, and for the run's training and test instructions beside yours,
it prints TL agreement (the fraction of sentences whose code equals their goal's training code) and success on
``--episodes`` episodes (a goal uniform over the set's goals, one of its sentences uniform); the three sets share the
episodes' goals and random keys, so their success rates are paired.

Every sentence also gets the agent's verdict (``talar_jax.confidence``: understood, ambiguous or not understood,
calibrated by the run's ``confidence.json``): beside plain agreement and success, each set reports its coverage (the
share of its sentences the agent acts on), the accuracy among those (the verdict's goal is the sentence's) and the
success of the paired episodes whose sentence it acts on. Risk against coverage: for each measure an agent could
act on (its calibrated confidence, the familiarity alone, the ensemble posterior of the likeliest goal), acting on the
sentences it ranks highest, the threshold that acts on a given share of a set and the error rate among those acted
on, so that you can pick a threshold for your own sentences. Your sentences are listed one by one (``--json``, and the
markdown table ``--markdown``): intended goal, decoded goal, confidence, verdict and, when the agent acts on it, the
success of ``--sentence-episodes`` episodes on its intended goal.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from pathlib import Path

import jax
import numpy as np

from experiments.cli import POSITIONAL, UsageError, check_outputs, write_output
from experiments.recipes import get_recipe
from experiments.reports import agent_command, load_agent
from talar_jax.agent import CONFIDENCE_FILE, Agent, AgentError, find_method_folder, read_config
from talar_jax.confidence import VERDICTS
from talar_jax.language import load_instructions, load_user_instructions
from talar_jax.report import counted


@dataclasses.dataclass(frozen=True)
class GeneralizeArgs:
    run_dir: Path = dataclasses.field(metadata=POSITIONAL)
    """A finished run folder (``runs/clevr`` or a method folder such as ``runs/clevr/talar``)."""
    instructions: Path
    """JSON file of your phrasings (format above)."""
    episodes: int = 200
    """Episodes per seed and instruction set."""
    json: Path | None = None
    """Also write the results here."""
    rng_seed: int = 0
    """Seed of the episodes' randomness."""
    sentence_episodes: int = 1
    """Episodes per sentence of yours the agent acts on (its per-sentence success; 0: none)."""
    markdown: Path | None = None
    """Write the per-sentence table of your sentences here (markdown)."""


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


RISK_MEASURES: tuple[str, ...] = ("confidence", "familiarity", "posterior")
"""The measures of the risk-coverage table: the verdict's calibrated confidence, the sentence's familiarity, and the
ensemble posterior of its likeliest goal."""
COVERAGES: tuple[float, ...] = (1.0, 0.9, 0.8, 0.5)


def risk_coverage(scores, actable, right, coverages=COVERAGES) -> list[dict]:
    """Acting on the sentences ``scores`` ranks highest among the ``actable`` ones (a decoded goal, asked for
    positively): per target share of all sentences, the lowest score acted on (the threshold), the share acted on from
    that threshold (ties may raise it; it stops at the actable share) and the risk: the share of those acted on that
    are not ``right``. None where nothing is acted on."""
    scores, actable, right = np.asarray(scores, float), np.asarray(actable, bool), np.asarray(right, bool)
    candidates = np.flatnonzero(actable)
    order = candidates[np.argsort(-scores[candidates], kind="stable")]
    rows = []
    for target in coverages:
        count = min(int(round(target * len(scores))), len(order))
        if count == 0:
            rows.append({"target": target, "threshold": None, "coverage": 0.0, "risk": None})
            continue
        threshold = float(scores[order[count - 1]])
        acted = actable & (scores >= threshold)
        rows.append(
            {
                "target": target,
                "threshold": threshold,
                "coverage": float(acted.mean()),
                "risk": float(1 - right[acted].mean()),
            }
        )
    return rows


def verdict_risk_coverage(verdicts, goals) -> dict[str, list[dict]]:
    """``risk_coverage`` of each of ``RISK_MEASURES`` for one set's verdicts and intended goals: an agent acting on a
    sentence pursues the goal its code decodes to, so it is right when that is the intended one."""
    actable = [v.decoded is not None and v.polarity == "positive" for v in verdicts]
    right = [v.decoded == goal for v, goal in zip(verdicts, goals, strict=True)]
    scores = {
        "confidence": [v.confidence for v in verdicts],
        "familiarity": [v.familiarity for v in verdicts],
        "posterior": [v.candidates[0][1] if v.candidates else 0.0 for v in verdicts],
    }
    return {measure: risk_coverage(scores[measure], actable, right) for measure in RISK_MEASURES}


def evaluate_seed(
    agent: Agent, sets: dict, episodes: int, rng_seed: int, sentence_episodes: int = 0
) -> tuple[dict[str, dict[str, float]], list[dict]]:
    """TL agreement and paired-episode success of every instruction set for one seed: every set plays the same
    goals with the same episode keys (the goals the user's sentences cover); with the verdicts' coverage, accuracy
    among the sentences acted on and success of the episodes whose sentence is acted on. Also returns one record per
    sentence of the user's set (with the success of ``sentence_episodes`` episodes on its goal when acted on)."""
    choice = np.random.default_rng(rng_seed)
    goal_pool = np.array(sorted(set(sets["yours"][1].tolist())))
    goals = goal_pool[choice.integers(0, len(goal_pool), episodes)]
    rng_episodes = jax.random.key(rng_seed)
    out, records = {}, []
    for name, (features, sentence_goals, sentences) in sets.items():
        codes = agent.translate_features(features)
        agree = [np.array_equal(code.round(3), agent.goal_code(goal)) for code, goal in zip(codes, sentence_goals)]
        verdicts = agent.judge(sentences, features)
        acts = np.array([v.acts for v in verdicts])
        right = np.array([v.goal == goal for v, goal in zip(verdicts, sentence_goals, strict=True)])
        rows = np.array([choice.choice(np.flatnonzero(sentence_goals == goal)) for goal in goals])
        success = agent.success_rate(codes[rows], goals, rng_episodes)
        out[name] = {
            "tl_agreement": float(np.mean(agree)),
            "success": float(np.mean(success)),
            "sentences": len(codes),
            "coverage": float(acts.mean()),
            "accuracy_acted": float(right[acts].mean()) if acts.any() else None,
            "success_acted": float(success[acts[rows]].mean()) if acts[rows].any() else None,
            "verdicts": {v: int(sum(x.verdict == v for x in verdicts)) for v in VERDICTS},
            "risk_coverage": verdict_risk_coverage(verdicts, sentence_goals),
        }
        if name == "yours":
            per_sentence = sentence_success(agent, codes, sentence_goals, acts, sentence_episodes, rng_seed)
            for index, (verdict, goal) in enumerate(zip(verdicts, sentence_goals, strict=True)):
                record = verdict.to_json()
                record["understood_goal"] = record.pop("goal")
                records.append({"goal": int(goal), **record, "success": per_sentence[index]})
    return out, records


def sentence_success(agent: Agent, codes, goals, acts, episodes: int, rng_seed: int) -> list[float | None]:
    """Per sentence: its success rate over ``episodes`` episodes on its goal when acted on, else None (one call)."""
    acted = np.flatnonzero(acts)
    out: list[float | None] = [None] * len(goals)
    if episodes < 1 or not len(acted):
        return out
    rows = np.repeat(acted, episodes)
    success = agent.success_rate(codes[rows], goals[rows], jax.random.key(rng_seed + 1))
    for index, value in zip(acted, success.reshape(len(acted), episodes).mean(1), strict=True):
        out[int(index)] = float(value)
    return out


def _pct(value) -> str:
    return "–" if value is None else f"{100 * value:.1f}"


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


def selective_report(per_seed: list[dict[str, dict[str, float]]]) -> str:
    """Per seed and set: coverage, accuracy among the sentences acted on, success of the episodes acted on."""
    names = list(per_seed[0])
    metrics = ("coverage", "accuracy_acted", "success_acted")
    lines = ["| seed | " + " | ".join(f"{n}: coverage | {n}: right among acted | {n}: success acted" for n in names)]
    lines[0] += " |"
    lines.append("|---|" + "---:|---:|---:|" * len(names))
    for seed, row in enumerate(per_seed):
        lines.append(f"| {seed} | " + " | ".join(_pct(row[n][m]) for n in names for m in metrics) + " |")
    cells = []
    for n in names:
        for m in metrics:
            values = [row[n][m] for row in per_seed if row[n][m] is not None]
            cells.append(f"{100 * np.mean(values):.1f}" if values else "–")
    lines.append("| mean | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def risk_coverage_report(per_seed: list[dict[str, dict]]) -> str:
    """Markdown: per set, measure and target share, the threshold, the share acted on and the risk, means over seeds
    (a seed with nothing acted on leaves the risk out of the mean)."""
    lines = [
        "| set | measure | target share | threshold (mean over seeds) | acted on | risk: wrong among acted |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for name in per_seed[0]:
        for measure in RISK_MEASURES:
            for index, target in enumerate(COVERAGES):
                rows = [row[name]["risk_coverage"][measure][index] for row in per_seed]
                thresholds = [r["threshold"] for r in rows if r["threshold"] is not None]
                risks = [r["risk"] for r in rows if r["risk"] is not None]
                cells = [
                    name,
                    measure,
                    f"{100 * target:.0f}",
                    f"{np.mean(thresholds):.3f}" if thresholds else "–",
                    f"{100 * np.mean([r['coverage'] for r in rows]):.1f}",
                    _pct(np.mean(risks)) if risks else "–",
                ]
                lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sentence_table(sentences: list[str], per_seed_records: list[list[dict]], names: list[str]) -> str:
    """Markdown: one row per sentence of yours, over the seeds: intended goal, decoded goal (the most common), mean
    confidence, the verdicts and the mean success of the seeds that acted."""
    lines = [
        "| sentence | intended goal | decoded goal | confidence | verdict | success when acted |",
        "|---|---|---|---:|---|---:|",
    ]
    for index, sentence in enumerate(sentences):
        records = [records[index] for records in per_seed_records]
        decoded = Counter(r["decoded_goal"] for r in records).most_common(1)[0][0]
        verdicts = Counter(r["verdict"] for r in records)
        verdict = ", ".join(f"{v} {c}/{len(records)}" for v, c in verdicts.most_common())
        success = [r["success"] for r in records if r["success"] is not None]
        cells = [
            sentence.replace("|", "\\|"),
            names[records[0]["goal"]],
            names[decoded] if decoded is not None else "none",
            f"{np.mean([r['confidence'] for r in records]):.2f}",
            verdict,
            _pct(np.mean(success)) if success else "–",
        ]
        lines.append("| " + " | ".join(cells) + " |")
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
        raise UsageError(f"--episodes must be >= 1, got {args.episodes}")
    if args.sentence_episodes < 0:
        raise UsageError(f"--sentence-episodes must be >= 0, got {args.sentence_episodes}")
    check_outputs((args.json, "--json", "file"), (args.markdown, "--markdown", "file"))
    folder = find_method_folder(args.run_dir, prefer="talar")
    seeds = int(read_config(folder)["seeds"])
    per_seed, per_sentence, sizes = [], [], {}
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
            if not agent.calibrated:
                print(f"confidence: default calibration (no {CONFIDENCE_FILE} in {folder})")
        row, records = evaluate_seed(agent, sets, args.episodes, args.rng_seed, args.sentence_episodes)
        per_seed.append(row)
        per_sentence.append(records)
        print(seed_line(seed, per_seed[-1]), flush=True)
    table = report(per_seed)
    print(table)
    print("selective (the agent acts only on the sentences it understood):\n")
    print(selective_report(per_seed))
    print("risk against coverage (act on the sentences a measure ranks highest; in %):\n")
    print(risk_coverage_report(per_seed))
    names = get_recipe(agent.env_name).goal_names()
    sentences_table = sentence_table(sets["yours"][2], per_sentence, names)
    if len(sets["yours"][2]) <= 60:
        print(sentences_table)
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(
            f"# {folder}: your sentences\n\n{table}\n{selective_report(per_seed)}\n"
            f"Risk against coverage (act on the sentences a measure ranks highest; in %):\n\n"
            f"{risk_coverage_report(per_seed)}\n{sentences_table}"
        )
        print(f"per-sentence table: {args.markdown}")
    yours = [
        {"sentence": sentence, "per_seed": [records[index] for records in per_sentence]}
        for index, sentence in enumerate(sets["yours"][2])
    ]
    result = {
        "run": str(folder),
        "episodes_per_seed": args.episodes,
        "sentences": sizes,
        "per_seed": per_seed,
        "calibrated": bool(agent.calibrated),
        "yours": yours,
    }
    write_output(args.json, json.dumps(result, indent=2))
    return result


run_command, main = agent_command(GeneralizeArgs, generalize, __doc__)

if __name__ == "__main__":
    raise SystemExit(main())
