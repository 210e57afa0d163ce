"""Markdown tables of ``experiments.calibrate``: the measures compared, every set and half, each acting seed, other
thresholds on the chosen confidence."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from experiments.generalize import risk_coverage
from talar_jax.confidence import Calibration, Measures
from talar_jax.confidence.fit import (
    CALIBRATION,
    HELD_OUT,
    SentenceSet,
    baseline_rates,
    category_rates,
    evaluate,
    familiarity_quantiles,
)


def pct(value) -> str:
    return "–" if value is None else f"{100 * value:.1f}"


def _acted_cells(result: dict, part: str) -> list[str]:
    """The shares acted on each set (of ``part``; train's of the calibration half), dev's right among acted."""
    held, train = result[part], result[CALIBRATION]["train"]
    return [
        pct(train["acted"]),
        pct(held["test"]["acted"]),
        pct(held["dev"]["acted"]),
        pct(held["dev"]["accuracy_acted"]),
        pct(1.0 - held["no_goal"]["acted"]),
        pct(1.0 - held["near_miss"]["acted"]) if "near_miss" in held else "–",
        pct(1.0 - held["ambiguous"]["acted"]),
    ]


def table(results: dict[str, dict], met: dict[str, bool], part: str = HELD_OUT) -> str:
    """Markdown: one row per measure, the held-out figures the targets name (``met``: whether its threshold kept the
    targets on the calibration half)."""
    lines = [
        "| measure | train acted | test acted | dev acted | dev right among acted | no-goal not acted | "
        "near-miss not acted | ambiguous not acted | ambiguous: verdict ambiguous | targets kept when calibrating |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for name, result in results.items():
        cells = [
            *_acted_cells(result, part),
            pct(result[part]["ambiguous"].get("ambiguous")),
            {True: "yes", False: "no (closest threshold)", None: "–"}[met.get(name)],
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sets_table(result: dict) -> str:
    """Markdown: every set and half of one measure (acted, right among acted, verdict shares)."""
    lines = [
        "| set | half | sentences | acted | right among acted | understood | ambiguous | not understood |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for part in (CALIBRATION, HELD_OUT):
        for set_name, entry in result[part].items():
            if set_name == "train" and part == HELD_OUT:
                continue
            label = "all" if set_name == "train" else part.replace("_", "-")
            cells = [
                str(entry["sentences"]),
                pct(entry["acted"]),
                pct(entry["accuracy_acted"]),
                pct(entry["understood"]),
                pct(entry["ambiguous"]),
                pct(entry["not_understood"]),
            ]
            lines.append(f"| {set_name} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


TRADE_OFF = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)


def trade_off_table(measures: Measures, sentences: SentenceSet, calibration: Calibration) -> str:
    """Markdown: the held-out shares at other thresholds on the same confidence (what the threshold trades)."""
    lines = [
        "| act from confidence | train acted | test acted | dev acted | dev right among acted | no-goal not acted | "
        "near-miss not acted | ambiguous not acted |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for threshold in sorted({*TRADE_OFF, round(calibration.act_threshold, 3)}):
        result = evaluate(measures, sentences, dataclasses.replace(calibration, act_threshold=threshold))
        chosen = " (chosen)" if threshold == round(calibration.act_threshold, 3) else ""
        cells = _acted_cells(result, HELD_OUT)
        lines.append(f"| {threshold:g}{chosen} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


RISK_SETS = ("test", "dev", "no_goal", "ambiguous")
"""The held-out sentences of the risk-coverage table: phrasings of a goal, and sentences an agent should not act on."""
RISK_SHARES = (1.0, 0.7, 0.6, 0.5, 0.4)
"""Target shares of those acted on: a third or more of them name no goal or no goal in particular, so the curve's
interesting part lies below 0.7."""


def risk_coverage_table(measures: Measures, sentences: SentenceSet, calibrations: dict[str, Calibration]) -> str:
    """Markdown: for each measure compared, acting on the held-out sentences (test, development, no goal, ambiguous)
    it scores highest, per target share of them, the threshold, the share acted on and the risk (acted on wrongly: a
    wrong goal, or any goal for a sentence that names none), means over acting seeds."""
    sets, parts, goals = sentences.arrays()
    rows = (parts == HELD_OUT) & np.isin(sets, RISK_SETS)
    lines = [
        "| measure | target share | threshold on its confidence (mean over seeds) | acted on | "
        "risk: wrong among acted |",
        "|---|---:|---:|---:|---:|",
    ]
    for label, calibration in calibrations.items():
        per_seed = []
        for seed in range(measures.num_seeds):
            decoded = np.asarray(measures.decoded[seed])[rows]
            scores = calibration.confidence(measures, seed)[rows]
            per_seed.append(risk_coverage(scores, decoded >= 0, decoded == goals[rows], RISK_SHARES))
        for index, target in enumerate(RISK_SHARES):
            at = [seed_rows[index] for seed_rows in per_seed]
            thresholds = [r["threshold"] for r in at if r["threshold"] is not None]
            risks = [r["risk"] for r in at if r["risk"] is not None]
            threshold = f"{np.mean(thresholds):.3f}" if thresholds else "-"
            risk = f"{pct(np.mean(risks))}" if risks else "-"
            coverage = pct(np.mean([r["coverage"] for r in at]))
            lines.append(f"| {label} | {pct(target)} | {threshold} | {coverage} | {risk} |")
    return "\n".join(lines) + "\n"


def seeds_table(result: dict, distinct: list[float]) -> str:
    """Markdown: per acting seed, the held-out shares acted on (train: all of it) and its goals with a code of their
    own (goals sharing a code cannot be told apart by its policy, so the agent does not act on them)."""
    lines = [
        "| seed | goals with their own code | train acted | test acted | dev acted | no-goal not acted | "
        "ambiguous not acted |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    held, train = result[HELD_OUT], result[CALIBRATION]["train"]
    for seed, own in enumerate(distinct):
        cells = [
            pct(own),
            pct(train["acted_per_seed"][seed]),
            pct(held["test"]["acted_per_seed"][seed]),
            pct(held["dev"]["acted_per_seed"][seed]),
            pct(1.0 - held["no_goal"]["acted_per_seed"][seed]),
            pct(1.0 - held["ambiguous"]["acted_per_seed"][seed]),
        ]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def report_text(measures, sentences, calibrations, results, chosen_label, chosen, description) -> tuple[str, dict]:
    """What ``experiments.calibrate`` prints (and ``--report`` writes), and the record ``--json`` writes."""
    result = results[chosen_label]
    met = {label: c.source.get("calibration_half_meets_targets") for label, c in calibrations.items()}
    baseline = baseline_rates(measures, sentences)
    categories = category_rates(measures, sentences, chosen)
    quantiles = familiarity_quantiles(measures, sentences)
    held = baseline[HELD_OUT]
    acting = "\n".join(f"- {k}: {100 * v:.1f} % not acted on" for k, v in categories.items())
    text = (
        f"measures compared (held-out half; mean over {description['seeds']} acting seeds):\n\n{table(results, met)}\n"
        f"acting on every decoded code (no measure), held-out: dev {pct(held['dev']['acted'])} % acted, "
        f"{pct(held['dev']['accuracy_acted'])} % right; no-goal {pct(1 - held['no_goal']['acted'])} % not acted on\n\n"
        f"chosen ({chosen_label}): temperature {chosen.temperature:g}, act from confidence "
        f"{chosen.act_threshold:.3f}, ambiguous from familiarity {chosen.familiar_threshold:.3f}\n\n"
        f"{sets_table(result)}\n"
        f"per acting seed (held-out):\n\n{seeds_table(result, description['distinct_goal_codes'])}\n"
        f"other thresholds on the same confidence (held-out):\n\n{trade_off_table(measures, sentences, chosen)}\n"
        "risk against coverage of each measure (held-out test, development, no-goal and ambiguous sentences; acting "
        "on those it scores highest):\n\n"
        f"{risk_coverage_table(measures, sentences, calibrations)}\n"
        f"no-goal sentences per category (both halves):\n{acting}\n\n"
        f"familiarity quantiles (0, 5, 50, 95, 100 %): {json.dumps(quantiles)}\n"
    )
    record = {
        "run": description,
        "calibration": chosen.to_json(),
        "results": results,
        "baseline": baseline,
        "no_goal_categories": categories,
        "familiarity_quantiles": quantiles,
        "calibrations": {k: v.to_json() for k, v in calibrations.items()},
    }
    return text, record
