"""Calibrate a run's translation confidence: when its agent acts, says it is not sure, or says it does not understand.

``python -m experiments.calibrate RUN_DIR [--out FILE] [--study] [--report FILE.md] [--json FILE]``

RUN_DIR is an ``experiments.clevr`` / ``experiments.kitchen`` run (its root or method folder) whose encoding can
read sentences; only the encoding's stage must be finished (for TALAR: the translator stage). The sets, their halves
and the fit are ``talar_jax.confidence.fit``'s: the run's training and test instructions, the development phrasings
(``--development``), and the sentences of ``--data`` that name no goal, near misses and ambiguous sentences, every
seed of the run acting in turn. The calibration is written to ``confidence.json`` in the method folder (``--out``
elsewhere), with a single-seed calibration inside for agents holding one seed's encoding; ``--study`` also fits and
measures the other measures compared in ``results/abstention.md``.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

import envs
from experiments.calibration_tables import report_text
from experiments.cli import POSITIONAL, UsageError, check_outputs, write_output
from experiments.recipes import get_recipe
from experiments.reports import agent_command
from talar_jax.agent import (
    CONFIDENCE_FILE,
    AgentError,
    find_method_folder,
    read_config,
    read_encoding,
    read_encoding_params,
)
from talar_jax.checkpoint import write_json_atomic
from talar_jax.confidence import Calibration, Measures, Understanding
from talar_jax.confidence.fit import (
    ALL,
    CALIBRATION,
    SETS,
    SentenceSet,
    by_pattern,
    fit_study,
    group_halves,
    half,
    held_out_figures,
    meets_targets,
    with_single_seed,
)
from talar_jax.encodings import ENCODING_FILE, EncodingArtifact, EncodingError
from talar_jax.language import (
    DEVELOPMENT_FILE,
    build_cache,
    cached_sentence_features,
    features_with_cache,
    load_encoder,
    load_instructions,
    load_user_instructions,
    readout_features,
)
from talar_jax.provenance import git_commit

ABSTENTION_FILE = Path(__file__).resolve().parent.parent / "talar_jax" / "language" / "data" / "abstention.json"
"""Sentences that name no goal, near misses and ambiguous sentences, per env (``{"<env>": {"no_goal": {"<category>":
[...]}, "near_miss": [...], "ambiguous": [{"sentence": ..., "goals": ...}]}}``; kitchen goals are sub-task names,
CLEVR goals a filter ``{"subject": [colours], "relation": [front|behind|left|right], "object": [colours]}`` on the
words the env's instruction format fills its patterns with (a relation named by a word of its phrase), a missing key
meaning any)."""


@dataclasses.dataclass(frozen=True)
class CalibrateArgs:
    run_dir: Path = dataclasses.field(metadata=POSITIONAL)
    """A run folder (``runs/kitchen`` or a method folder such as ``runs/kitchen/talar``)."""
    out: Path | None = None
    """Where to write the calibration (default: ``confidence.json`` in the run's method folder)."""
    data: Path = ABSTENTION_FILE
    """Sentences that name no goal, near misses and ambiguous sentences, per env (the package file's format)."""
    development: Path = DEVELOPMENT_FILE
    """Development phrasings (``experiments.generalize``'s format)."""
    reject_target: float = 0.98
    """Share of the calibration half's no-goal sentences that must not be acted on."""
    accuracy_target: float = 0.98
    """Share of the calibration half's development and test sentences acted on that must be acted on right."""
    coverage_target: float = 0.95
    """Share of the calibration half's development and test sentences that must be acted on: a sentence that names
    its goal outright is acted on, whatever asking back ambiguous ones would gain."""
    ambiguous_weight: float = 1 / 3
    """What not acting on an ambiguous sentence is worth against acting on a new phrasing (per share of each set)."""
    ensemble: bool = True
    """Average the goal posterior over the run's seeds (else each acting seed's own)."""
    study: bool = False
    """Also fit and measure the other measures (familiarity alone, one seed's posterior, ...)."""
    report: Path | None = None
    """Write the tables as markdown here."""
    json: Path | None = None
    """Write every number here."""


# --- the run -----------------------------------------------------------------------------------------------------
def run_encoding(folder: Path) -> EncodingArtifact:
    """The run's encoding record, or for a run whose record is not written yet (it is written when the policy stage
    starts) the one its method registers for its config, built in memory (nothing is written into the run)."""
    if (folder / ENCODING_FILE).is_file():
        return read_encoding(folder)
    from experiments.methods import get_method
    from experiments.reports import config_from_json

    config = config_from_json(read_config(folder))
    return get_method(config.method).encoding(config, len(get_recipe(config.env).goal_names()))


def method_folder(run_dir: Path) -> Path:
    """The method folder of ``run_dir``; unlike an agent's, its policy stage need not be finished."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise AgentError(f"run folder {run_dir} does not exist")
    if (run_dir / "config.json").is_file():
        return run_dir
    try:
        return find_method_folder(run_dir, prefer="talar")
    except AgentError:
        candidates = sorted(p.parent for p in run_dir.glob("*/config.json"))
        preferred = [c for c in candidates if c.name == "talar"] or candidates
        if len(preferred) != 1:
            raise AgentError(f"{run_dir} holds no single experiment run (no <method>/config.json)") from None
        return preferred[0]


# --- the sentences -----------------------------------------------------------------------------------------------
def meant_goals(env: str, spec: Any, names: list[str]) -> tuple[int, ...]:
    """The goal ids an ambiguous sentence's ``goals`` entry names (see ``ABSTENTION_FILE``)."""
    if isinstance(spec, list):
        lowered = [n.lower() for n in names]
        unknown = [g for g in spec if str(g).lower() not in lowered]
        if unknown:
            raise ValueError(f"unknown goals {unknown} in {ABSTENTION_FILE.name}; valid: {', '.join(names)}")
        return tuple(lowered.index(str(g).lower()) for g in spec)
    if isinstance(spec, dict) and env.startswith("clevr"):
        unknown = set(spec) - {"subject", "relation", "object"}
        if unknown:
            raise ValueError(f"unknown keys {sorted(unknown)} in a {env} goal filter of {ABSTENTION_FILE.name}")
        # Each goal's words, as the env's instruction format fills a pattern of its three placeholders.
        probe = {"clevr_patterns": ["{subject}|{relation}|{object}"]}
        fillings, goals = envs.instruction_format(env).read_user(probe, ABSTENTION_FILE)
        meant = []
        for filling, goal in zip(fillings, goals, strict=True):
            subject, relation, object_ = filling.split("|")
            if (
                subject in spec.get("subject", [subject])
                and object_ in spec.get("object", [object_])
                and any(word in relation.split() for word in spec.get("relation", relation.split()))
            ):
                meant.append(int(goal))
        return tuple(meant)
    raise ValueError(f"cannot read the goals {spec!r} of an ambiguous {env} sentence")


def gather_sentences(env: str, data_file: Path, development: Path, names: list[str]) -> SentenceSet:
    """The five sets of the module docstring with their halves."""
    out = SentenceSet()
    num_goals = len(names)
    train, test = load_instructions(env, "train"), load_instructions(env, "test")
    for sentence, goal in zip(train.sentences, train.goal_ids, strict=True):
        out.add(sentence, "train", ALL, goal)
    clevr_like = env.startswith("clevr")
    parts = (
        by_pattern(len(test), num_goals) if clevr_like else group_halves(test.goal_ids.tolist())
    )  # the test sentences of a kitchen sub-task alternate; CLEVR's patterns alternate
    for sentence, goal, part in zip(test.sentences, test.goal_ids, parts, strict=True):
        out.add(sentence, "test", part, goal)
    dev, dev_goals = load_user_instructions(development, env)
    parts = by_pattern(len(dev), num_goals) if clevr_like else group_halves(dev_goals.tolist())
    for sentence, goal, part in zip(dev, dev_goals, parts, strict=True):
        out.add(sentence, "dev", part, goal)
    data = json.loads(Path(data_file).read_text())
    key = "clevr" if clevr_like else "kitchen" if env.startswith("kitchen") else env
    if key not in data:
        raise ValueError(f"{data_file} has no {key!r} entry (keys: {', '.join(data)})")
    for category, sentences in data[key]["no_goal"].items():
        for index, sentence in enumerate(sentences):
            out.add(sentence, "no_goal", half(index), category=category)
    for index, sentence in enumerate(data[key].get("near_miss", [])):
        out.add(sentence, "near_miss", half(index))
    for index, entry in enumerate(data[key]["ambiguous"]):
        out.add(entry["sentence"], "ambiguous", half(index), meant=meant_goals(env, entry["goals"], names))
    return out


# --- fitting -----------------------------------------------------------------------------------------------------
STUDY: dict[str, tuple[tuple[str, ...], bool]] = {
    "familiarity alone": (("familiarity",), False),
    "own posterior (1 seed)": (("own_goal_logit",), False),
    "own posterior + runner-up (1 seed)": (("goal_logit", "runner_up_logit"), False),
    "familiarity + own posterior (1 seed)": (("familiarity", "goal_logit", "runner_up_logit"), False),
    "ensemble posterior": (("goal_logit", "runner_up_logit"), True),
    "familiarity + ensemble posterior": (("familiarity", "goal_logit", "runner_up_logit"), True),
    "familiarity + ensemble + own posterior": (
        ("familiarity", "goal_logit", "runner_up_logit", "own_goal_logit"),
        True,
    ),
}
"""The measures the study compares: (features, ensemble)."""
CHOSEN = "familiarity + ensemble posterior"
SINGLE_SEED = "familiarity + own posterior (1 seed)"


# --- the command -------------------------------------------------------------------------------------------------
def measure_run(folder: Path, sentences: SentenceSet) -> tuple[Measures, dict]:
    """Every seed's measures of every sentence of a run (its method folder), and the run's description (its seeds'
    goals with a code of their own among them). The encoding comes from the run's record, or its method's
    registration."""
    try:
        artifact = run_encoding(folder)
    except (EncodingError, KeyError, ValueError) as error:
        raise AgentError(f"cannot read the encoding of {folder}: {error}") from None
    if not artifact.readable:
        raise AgentError(artifact.unreadable_reason)
    params = read_encoding_params(folder, artifact)
    raw = read_config(folder)
    try:
        encoder = load_encoder(raw.get("encoder"))
        cache = build_cache(raw["env"], encoder, progress=False)
        cached = readout_features(cache, artifact.readout, encoder)
        train = np.flatnonzero(cache.is_train)
        understanding = Understanding(
            artifact, params, cached[train], cache.goal_ids[train], int(cache.num_goals), encoder.embedding_dim
        )
        features = features_with_cache(
            sentences.sentences,
            cache.sentences,
            cached,
            lambda fresh: cached_sentence_features(
                encoder, fresh, artifact.readout, description="calibration sentences"
            ),
        )
    except (EncodingError, ValueError) as error:
        raise AgentError(str(error)) from None
    measures = Measures.concatenate(
        [understanding.measure(features[i : i + 512]) for i in range(0, len(features), 512)]
    )
    codes = understanding.goal_codes.round().astype(int)  # (K, G, size)
    description = {
        "distinct_goal_codes": [float(np.mean([(c == c[g]).all(1).sum() == 1 for g in range(len(c))])) for c in codes],
        "run": str(folder),
        "env": raw["env"],
        "method": raw.get("method", Path(folder).name),
        "encoding_kind": artifact.kind,
        "seeds": understanding.num_seeds,
        "scored_heads": understanding.scored,
        "encoder": encoder.name,
    }
    return measures, description


def provenance(args: CalibrateArgs, chosen: Calibration, result: dict, description: dict, counts: dict) -> dict:
    """The calibration file's ``source``: the run, the data, the command, what the held-out half measured."""
    return {
        **chosen.source,
        **description,
        "made": datetime.date.today().isoformat(),
        "commit": git_commit(),
        "command": "python -m experiments.calibrate " + " ".join(sys.argv[1:]) if sys.argv[1:] else None,
        "data": {"abstention": str(args.data), "development": str(args.development)},
        "sentences": counts,
        "targets": {
            "reject": args.reject_target,
            "accuracy": args.accuracy_target,
            "ambiguous_weight": args.ambiguous_weight,
            "coverage": args.coverage_target,
        },
        "held_out": held_out_figures(result),
        "train_acted": result[CALIBRATION]["train"]["acted"],
        "meets_targets": meets_targets(result, args.reject_target, args.accuracy_target, args.coverage_target),
    }


def check_args(args: CalibrateArgs) -> Path:
    """The method folder; one ``UsageError`` for a bad option, an ``AgentError`` for a run it cannot read."""
    for name in ("reject_target", "accuracy_target"):
        if not 0.0 < getattr(args, name) <= 1.0:
            raise UsageError(f"--{name.replace('_', '-')} must lie in (0, 1], got {getattr(args, name)}")
    if not 0.0 <= args.coverage_target <= 1.0:
        raise UsageError(f"--coverage-target must lie in [0, 1], got {args.coverage_target}")
    if args.ambiguous_weight < 0:
        raise UsageError(f"--ambiguous-weight must be >= 0, got {args.ambiguous_weight}")
    check_outputs((args.out, "--out", "file"), (args.report, "--report", "file"), (args.json, "--json", "file"))
    return method_folder(args.run_dir)


def calibrate(args: CalibrateArgs) -> dict:
    folder = check_args(args)
    env = read_config(folder)["env"]
    try:
        sentences = gather_sentences(env, args.data, args.development, get_recipe(env).goal_names())
    except (OSError, ValueError, KeyError) as error:
        raise AgentError(f"cannot read the sentences: {error}") from None
    measures, description = measure_run(folder, sentences)
    counts = {s: int(np.sum(np.array(sentences.sets) == s)) for s in SETS}
    seeds = description["seeds"]
    print(f"run: {folder} ({description['method']}, {env}, {seeds} seeds); sentences: {counts}", flush=True)
    targets = (args.reject_target, args.accuracy_target, args.ambiguous_weight, args.coverage_target)
    studied = STUDY if args.study else {CHOSEN: STUDY[CHOSEN]}
    calibrations, results = fit_study(measures, sentences, studied, targets, args.ensemble and seeds > 1)
    chosen = with_single_seed(calibrations[CHOSEN], measures, sentences, targets)
    chosen = dataclasses.replace(chosen, source=provenance(args, chosen, results[CHOSEN], description, counts))
    out = args.out if args.out is not None else folder / CONFIDENCE_FILE
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, chosen.to_json())
    text, record = report_text(measures, sentences, calibrations, results, CHOSEN, chosen, description)
    print(text)
    print(f"targets met (held-out): {json.dumps(chosen.source['meets_targets'])}")
    print(f"calibration: {out}")
    write_output(args.report, f"# Confidence calibration of {folder}\n\ncommit {chosen.source['commit']}\n\n{text}")
    write_output(args.json, json.dumps(record, indent=2))
    return record


run_command, main = agent_command(CalibrateArgs, calibrate, __doc__)

if __name__ == "__main__":
    raise SystemExit(main())
