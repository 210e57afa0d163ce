"""Fit and measure the polarity classifier the shipped agents read: ``python -m experiments.polarity``.

Builds both envs' polarity sets (``talar_jax.language.polarity``: sentences that ask for a task, ask not to do it, or
ask for its opposite) and their sentences that name something the env does not have (``unknown_set``), reads every
sentence's token states with the encoder (cached; with ``--tuned-layers`` the states entering the layers it
fine-tunes), fits the heads on the train halves of both envs together, and measures
them on each half: per class, the share of sentences an agent would act on as the task (probability of
``positive`` at least the threshold), and the risk-coverage curve of that threshold. Writes the parameters
(``polarity.msgpack``, a fine-tuned top in float16) and their
record (``polarity.json``: config, encoder, measures) into ``--out`` (default: beside the shipped agents, where
``talar_jax.agent`` finds them), and the measures as a table into ``--report``. Deterministic: the same code and
encoder give the same bytes.

``--development`` fits on the train half's own train share and measures its development share, where settings
(``--tuned-layers``, ``--top-learning-rate``, ...) are compared; it writes only ``--report``. ``--classes 3`` fits
without the unknown sentences, as the classifier was before that class.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from pathlib import Path

import flax.serialization
import numpy as np

from experiments.cli import ArgumentParser, check_outputs, command
from experiments.reports import write_measures
from talar_jax import runtime
from talar_jax.agent import POLARITY_STEM, SHIPPED_AGENTS_DIR
from talar_jax.confidence.polarity import (
    POSITIVE,
    PolarityConfig,
    fit_polarity,
    judged_classes,
    polarity_probabilities,
    polarity_states,
    shipped_params,
)
from talar_jax.language import cached_sentence_features, load_encoder, stack_features
from talar_jax.language.cache import TOKEN_READOUT, default_cache_dir
from talar_jax.language.polarity import CLASSES, PolaritySet, polarity_set, unknown_set
from talar_jax.provenance import provenance

ENVS = ("kitchen", "clevr")
THRESHOLDS = (0.5, 0.7, 0.9, 0.95, 0.99)


def measures(probabilities: np.ndarray, labels: np.ndarray, threshold: float, config: PolarityConfig) -> dict:
    """Per class the share acted on as the task (``judged_classes`` at ``act_threshold`` = threshold); coverage and
    risk over the set: the share acted on, and the share of non-positive sentences among those."""
    acted = judged_classes(probabilities, dataclasses.replace(config, act_threshold=threshold)) == POSITIVE
    shares = {
        label: float(acted[labels == k].mean()) if (labels == k).any() else None for k, label in enumerate(CLASSES)
    }
    risk = float((labels[acted] != POSITIVE).mean()) if acted.any() else 0.0
    return {"threshold": threshold, "acted": shares, "coverage": float(acted.mean()), "risk": risk}


def report_table(record: dict) -> str:
    """Markdown: per env and half, the share acted on of each class at the agents' threshold, and the curve."""
    lines = [
        "| env | half | sentences | " + " | ".join(f"{label} acted on" for label in CLASSES) + " |",
        "|---|---|---|" + "---|" * len(CLASSES),
    ]
    curve = [
        "| env | half | threshold | coverage (share acted on) | risk (not positive among acted) |",
        "|---|---|---|---|---|",
    ]
    for env, halves in record["measures"].items():
        for half, rows in halves.items():
            at = next(row for row in rows["curve"] if row["threshold"] == record["config"]["act_threshold"])
            shares = [at["acted"].get(label) for label in CLASSES]
            cells = ["-" if share is None else f"{100 * share:.1f} %" for share in shares]
            lines.append(f"| {env} | {half} | {rows['sentences']} | {' | '.join(cells)} |")
            curve += [
                f"| {env} | {half} | {row['threshold']} | {100 * row['coverage']:.1f} % | {100 * row['risk']:.1f} % |"
                for row in rows["curve"]
            ]
    return "\n".join(lines) + "\n\nRisk against coverage as the threshold moves:\n\n" + "\n".join(curve) + "\n"


def joined(parts: list[PolaritySet]) -> PolaritySet:
    """One set of the rows of ``parts`` (of one env), in order."""
    return PolaritySet(
        parts[0].env,
        tuple(s for part in parts for s in part.sentences),
        *(np.concatenate([getattr(part, name) for part in parts]) for name in ("labels", "goals", "held_out")),
    )


def cached_states(encoder, sentences: tuple[str, ...], config: PolarityConfig) -> np.ndarray:
    """``polarity_states`` of the sentences, kept in the language cache folder (float16, as the token readout's)."""
    if not config.tuned_layers:
        return cached_sentence_features(encoder, sentences, TOKEN_READOUT, progress=True)
    payload = json.dumps(["polarity-states", encoder.cache_key, config.tuned_layers, list(sentences)])
    path = default_cache_dir() / f"polarity-{hashlib.sha256(payload.encode()).hexdigest()[:24]}.npy"
    if path.is_file():
        return np.load(path).astype(np.float32)
    states = polarity_states(encoder, sentences, config, progress=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial.npy")
    np.save(partial, states.astype(np.float16))
    os.replace(partial, path)
    return states


def run_command(argv: list[str] | None = None) -> dict:
    runtime.start()
    parser = ArgumentParser(prog="python -m experiments.polarity", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=SHIPPED_AGENTS_DIR, help="folder of the parameters and record")
    parser.add_argument("--report", type=Path, default=None, help="a markdown file for the measures (optional)")
    parser.add_argument(
        "--development",
        action="store_true",
        help="fit on the train half's own train share and measure its development share (for choosing settings; "
        "writes the report only, never the shipped files)",
    )
    defaults = PolarityConfig()
    settings = ("tuned_layers", "top_learning_rate", "learning_rate", "steps", "positive_weight", "token_dropout")
    for name in (*settings, "classes"):
        kind = type(getattr(defaults, name))
        parser.add_argument(
            f"--{name.replace('_', '-')}", type=kind, default=None, help=f"default {getattr(defaults, name)}"
        )
    args = parser.parse_args(argv)
    check_outputs((args.out, "--out", "folder"), (args.report, "--report", "file"))
    overrides = {name: value for name, value in vars(args).items() if hasattr(defaults, name) and value is not None}
    config = dataclasses.replace(defaults, **overrides)
    if config.classes not in (len(CLASSES) - 1, len(CLASSES)):
        parser.error(f"--classes must be {len(CLASSES) - 1} (without the unknown class) or {len(CLASSES)}")
    encoder = load_encoder(None)
    if not 0 <= config.tuned_layers <= encoder.config.num_hidden_layers:
        parser.error(f"--tuned-layers must be 0 .. {encoder.config.num_hidden_layers}, got {config.tuned_layers}")
    print("reading the polarity sets' states (cached after the first run)", flush=True)
    words = encoder.whole_words()
    sets, features = {}, {}
    for env in ENVS:  # the states of the whole sets, cached once for both the development split and the halves
        makers = [polarity_set, functools.partial(unknown_set, words=words)][: config.classes - len(CLASSES) + 2]
        parts, rows = [], []
        for make in makers:
            whole = make(env)
            states = cached_states(encoder, whole.sentences, config)
            parts.append(make(env, development=True) if args.development else whole)
            rows += list(states[~whole.held_out] if args.development else states)
        sets[env], features[env] = joined(parts), stack_features(rows)
    train = [(features[env][~s.held_out], s.labels[~s.held_out]) for env, s in sets.items()]
    tokens = stack_features([row for features_of_env, _ in train for row in features_of_env])
    print(f"fitting {config.members} heads on {len(tokens)} sentences", flush=True)
    fitted = fit_polarity(tokens, np.concatenate([y for _, y in train]), config, encoder, progress=True)
    params = shipped_params(fitted)  # measured as shipped: the top rounded to float16
    record = {**provenance(), "config": dataclasses.asdict(config), "labels": list(CLASSES[: config.classes])}
    record.update(encoder=encoder.name, encoder_cache_key=encoder.cache_key, measures={})
    encoder_config = encoder.config if config.tuned_layers else None
    for env, s in sets.items():
        probabilities = polarity_probabilities(params, features[env], config, encoder_config)
        record["measures"][env] = {
            half: {
                "sentences": int((s.held_out == held).sum()),
                "curve": [
                    measures(probabilities[s.held_out == held], s.labels[s.held_out == held], t, config)
                    for t in THRESHOLDS
                ],
            }
            for half, held in (("train", False), ("held_out", True))
        }
    if args.development:
        table = "Development split of the train half (held_out: its development share).\n\n" + report_table(record)
        if args.report is not None:
            args.report.write_text(f"Made by `{record['command']}` at commit {record['commit']}.\n\n{table}")
        print(table)
        return record
    state = flax.serialization.msgpack_serialize(flax.serialization.to_state_dict(params))
    write_measures(args.out, POLARITY_STEM, state, record, report_table(record), args.report)
    return record


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
