"""Fit and measure the clause parser the shipped agents read: ``python -m experiments.clauses``.

Builds both envs' compound instructions (``talar_jax.language.compound``: one sentence asking for several tasks in an
order, from templates, joins and phrasings in a train and a held-out half), reads every piece's encoder state, fits
the tagger (``talar_jax.clauses``) on the train halves of both envs together and measures it on the held-out halves:
the share of sentences split into exactly the right clauses in the right order, and, through the shipped agents,
the share whose clauses give the right goals in the right order (sentences with a negated or opposite clause: the
share the agent refuses). A plain instruction must stay one clause: the share of the envs' training and test
instructions parsed as one is measured too. Writes the parameters (``clauses.msgpack``) and their record
(``clauses.json``: config, encoder, measures) into ``--out`` (default: beside the shipped agents, where
``talar_jax.agent`` finds them), and the measures as a table into ``--report``. Deterministic for a code and encoder.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import flax.serialization
import numpy as np

from experiments.cli import READERS, ArgumentParser, check_outputs, command
from experiments.reports import write_measures
from talar_jax import runtime
from talar_jax.agent import CLAUSES_STEM, SHIPPED_AGENTS_DIR, load, read_shipped_model
from talar_jax.clauses import (
    ClauseParserConfig,
    fit_clause_parser,
    parse_clauses,
    piece_states,
    piece_targets,
    stored,
)
from talar_jax.language import load_encoder
from talar_jax.language.compound import compound_set
from talar_jax.language.instructions import load_instructions
from talar_jax.provenance import provenance

ENVS = ("kitchen", "clevr")
TRAIN_SENTENCES = 2000
"""Compound sentences per env in the train half."""
HELD_OUT_SENTENCES = 300
"""Compound sentences per env in the held-out half."""
EXTENSIONS = ("json", "msgpack")
"""A fitted parser's two files: its record and its parameters."""


def _normalised(text: str) -> str:
    return text.strip(" .,;:!?").lower()


def measure(agent, sentences, parsed) -> dict:
    """Per held-out set: clauses exactly right (text and order), clause count right, and through ``agent`` the right
    goals in the right order (sentences whose clauses all ask for their task) and refusals (the others)."""
    exact = [
        [_normalised(c.text) for c in clauses] == [_normalised(x) for x in s.segments()]
        for s, clauses in zip(sentences, parsed, strict=True)
    ]
    counted = [len(clauses) == len(s.goals) for s, clauses in zip(sentences, parsed, strict=True)]
    right_goals, refused = [], []
    for s, plan in zip(sentences, agent.plans([s.text for s in sentences]), strict=True):
        if all(s.positive):
            right_goals.append(plan.acts and plan.goals == s.goals)
        else:
            refused.append(not plan.acts)
    return {
        "sentences": len(sentences),
        "clauses_exact": float(np.mean(exact)),
        "clause_count_right": float(np.mean(counted)),
        "positive_sentences": len(right_goals),
        "right_goals_in_order": float(np.mean(right_goals)) if right_goals else None,
        "with_a_refused_clause": len(refused),
        "refused": float(np.mean(refused)) if refused else None,
    }


def report_table(record: dict) -> str:
    """Markdown: per env, the held-out measures and the share of plain instructions kept whole."""
    lines = [
        "| env | held-out sentences | clauses exactly right | right goals in the right order | chains with a "
        "negated clause refused | plain instructions kept one clause (train / test) |",
        "|---|---|---|---|---|---|",
    ]
    for env, m in record["measures"].items():
        held, whole = m["held_out"], m["plain_instructions_one_clause"]
        refused = (
            "n/a" if held["refused"] is None else f"{100 * held['refused']:.1f} % of {held['with_a_refused_clause']}"
        )
        lines.append(
            f"| {env} | {held['sentences']} | {100 * held['clauses_exact']:.1f} % | "
            f"{100 * held['right_goals_in_order']:.1f} % of {held['positive_sentences']} | {refused} | "
            f"{100 * whole['train']:.1f} % / {100 * whole['test']:.1f} % |"
        )
    return "\n".join(lines) + "\n"


def run_command(argv: list[str] | None = None) -> dict:
    runtime.start()
    parser = ArgumentParser(prog="python -m experiments.clauses", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=SHIPPED_AGENTS_DIR, help="folder of the parameters and record")
    parser.add_argument("--report", type=Path, default=None, help="a markdown file for the measures (optional)")
    parser.add_argument(
        "--sentences", type=READERS[int], default=TRAIN_SENTENCES, help="compound sentences per env to fit on"
    )
    parser.add_argument(
        "--parser",
        type=Path,
        default=None,
        help="measure the parser already fitted in this folder (its clauses.msgpack and clauses.json) instead of "
        "fitting one; --out is then not written",
    )
    args = parser.parse_args(argv)
    if args.sentences < 1:
        parser.error(f"--sentences must be at least 1, got {args.sentences}")
    check_outputs((args.out, "--out", "folder"), (args.report, "--report", "file"))
    if args.parser is not None and not all((args.parser / f"{CLAUSES_STEM}.{ext}").is_file() for ext in EXTENSIONS):
        parser.error(f"--parser {args.parser} holds no {CLAUSES_STEM}.json and {CLAUSES_STEM}.msgpack")
    encoder = load_encoder(None)
    if args.parser is not None:
        fitted = read_shipped_model(encoder, CLAUSES_STEM, "python -m experiments.clauses", args.parser)
        if fitted is None:
            parser.error(f"--parser {args.parser} holds no clause parser of this encoder")
        params, fitted_record = fitted
        config = ClauseParserConfig(**fitted_record["config"])
        record = {**provenance(), "config": fitted_record["config"], "parser": str(args.parser)}
        record["measures"] = measure_parser(params, config, encoder)
        write_measures_report(record, args.report)
        return record
    config = ClauseParserConfig()
    words = encoder.whole_words(min_length=2) if config.role_share else ()
    train = [
        s
        for seed, env in enumerate(ENVS)
        for s in compound_set(
            env,
            False,
            args.sentences,
            seed=seed,
            words=words,
            role_share=config.role_share,
            trim_share=config.trim_share,
        )
    ]
    print(f"reading the word-piece states of {len(train)} compound sentences", flush=True)
    sequences, place, shift, joins = piece_targets(encoder, train)
    states = piece_states(encoder, sequences, np.float16, config)
    print(f"fitting the clause tagger ({config.steps} steps)", flush=True)
    params = fit_clause_parser(
        states,
        place,
        shift,
        joins,
        config,
        encoder,
        lambda step, loss: print(f"  step {step}: loss {loss:.4f}", flush=True),
    )
    params = stored(params)  # measured as shipped
    del states
    record = {**provenance(), "config": dataclasses.asdict(config), "train_sentences_per_env": args.sentences}
    record.update(encoder=encoder.name, encoder_cache_key=encoder.cache_key, measures={})
    params_bytes = flax.serialization.msgpack_serialize(params)
    record["measures"] = measure_parser(params, config, encoder)
    write_measures(args.out, CLAUSES_STEM, params_bytes, record, report_table(record), args.report)
    return record


def measure_parser(params, config: ClauseParserConfig, encoder) -> dict:
    """Per env, the parser's measures on the held-out compound sentences and the share of plain instructions it
    keeps whole."""
    measures = {}
    for env_index, env in enumerate(ENVS):
        print(f"measuring on {env}'s held-out compound sentences", flush=True)
        held = compound_set(env, True, HELD_OUT_SENTENCES, seed=len(ENVS) + env_index)
        agent = load(env)
        agent.clause_parser = (params, config)  # the parser measured, wherever it is stored
        parsed = parse_clauses(params, encoder, [s.text for s in held], config)
        whole = {}
        for split in ("train", "test"):
            plain = list(load_instructions(env, split).sentences)
            whole[split] = float(np.mean([len(c) == 1 for c in parse_clauses(params, encoder, plain, config)]))
        measures[env] = {"held_out": measure(agent, held, parsed), "plain_instructions_one_clause": whole}
    return measures


def write_measures_report(record: dict, report: Path | None) -> None:
    """The measures of a parser measured again (``--parser``): printed, and written to ``report`` when given."""
    table = report_table(record)
    if report is not None:
        report.write_text(f"Made by `{record['command']}` at commit {record['commit']}.\n\n{table}")
    print(table)


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
