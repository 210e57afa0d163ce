"""Translators with and without paraphrase augmentation, trained on a finished run's referential game, compared by
TL agreement on the training, test and development instructions (instructions phrased in ways no one trained on).
No policy is trained: agreement is what the translator contributes.

    python -m experiments.analysis.translator_robustness runs/kitchen-4M --env kitchen --paraphrases 0 8 16 \
        --json out.json

RUN is an experiment folder with ``oracle/dataset`` and ``talar/task_language/params.msgpack``; the run is assumed to
use the env recipe's defaults (readout, TL spec, translator settings), which this reads from ``default_config``;
``--tokens on`` / ``off`` sets whether the translators read token states (``TalarConfig.translator_tokens``).
For every ``--paraphrases`` value (0: the paper's translator) it trains one translator per seed of the run from the
same seed keys and prints agreement per seed and mean ± std; the translators are kept in
``RUN/translator-robustness/`` and reused by a later call. With ``--episodes N`` it also runs the run's own
policies (``RUN/talar``) on the codes of each translator, on paired episodes as ``experiments.generalize`` does: the
success a swapped-in translator would give, valid when it keeps the goals' training codes (printed per seed).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.cli import ArgumentParser, check_outputs, command
from experiments.config import default_config, resolve
from experiments.generalize import evaluate_seed
from experiments.methods import MethodContext, paraphrased_data, stage_seed_keys, translator_readout
from experiments.reports import load_agent
from talar_jax import runtime
from talar_jax.agent import Agent
from talar_jax.checkpoint import load_tree, save_tree
from talar_jax.dataset import TaskDataset
from talar_jax.language import (
    DEVELOPMENT_FILE,
    build_cache,
    cached_sentence_features,
    load_encoder,
    load_instructions,
    load_user_instructions,
    readout_features,
)
from talar_jax.optim import fit_seeds
from talar_jax.talar import (
    make_generate_task_language,
    make_task_language_data,
    make_train_translator,
    make_translate,
    task_language_quality,
)


class SwappedTranslator:
    """A run's agent whose translator is replaced (its policy unchanged): what ``evaluate_seed`` reads."""

    def __init__(self, agent: Agent, translate, goal_codes: dict[int, np.ndarray]):
        self.agent, self._translate, self._goal_codes = agent, translate, goal_codes

    def translate_features(self, features: np.ndarray) -> np.ndarray:
        return self._translate(features)

    def goal_code(self, goal: int) -> np.ndarray:
        return self._goal_codes[int(goal)]

    def success_rate(self, *args, **kwargs) -> np.ndarray:
        return self.agent.success_rate(*args, **kwargs)


def agreement(codes: np.ndarray, goals: np.ndarray, goal_codes: dict[int, np.ndarray]) -> float:
    return float(np.mean([np.array_equal(c, goal_codes.get(int(g))) for c, g in zip(codes, goals)]))


def _parser() -> ArgumentParser:
    parser = ArgumentParser(prog="python -m experiments.analysis.translator_robustness", description=__doc__)
    parser.add_argument("run", type=Path, help="a finished experiment folder (RUN above), e.g. runs/kitchen")
    parser.add_argument("--env", required=True, choices=["clevr", "kitchen"], help="the env of RUN")
    parser.add_argument("--seeds", type=int, default=5, help="translator seeds, the first of RUN's (default: 5)")
    parser.add_argument(
        "--paraphrases", type=int, nargs="+", default=[0, 8], help="paraphrase counts to compare (default: 0 8)"
    )
    parser.add_argument(
        "--probability", type=float, default=0.5, help="chance a batch row reads a paraphrase (default: 0.5)"
    )
    parser.add_argument("--steps", type=int, default=None, help="translator steps (default: the recipe's)")
    parser.add_argument("--learning-rate", type=float, default=None, help="translator LR (default: the recipe's)")
    parser.add_argument(
        "--development",
        type=Path,
        default=DEVELOPMENT_FILE,
        help="JSON file of development instructions (default: the project's development.json)",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    parser.add_argument("--unknown-words", action="store_true", help="paraphrases also use unknown words")
    parser.add_argument("--front-phrases", action="store_true", help="paraphrases also front the closing phrase")
    parser.add_argument(
        "--tokens", choices=["on", "off"], default=None, help="translator reads token states (default: the recipe's)"
    )
    parser.add_argument("--episodes", type=int, default=0, help="success episodes per seed and set (0: none)")
    parser.add_argument("--show-failures", type=int, default=10, help="development sentences most often missed")
    return parser


def _config(args):
    """The run's resolved recipe config with the command line's translator settings."""
    config = resolve(default_config(args.env, seeds=args.seeds, out=args.run, progress=False))
    changes = {}
    if args.steps:
        changes["translator_steps"] = args.steps
    if args.learning_rate:
        changes["translator_learning_rate"] = args.learning_rate
    if args.tokens is not None:
        changes["translator_tokens"] = args.tokens == "on"
    return dataclasses.replace(config, talar=dataclasses.replace(config.talar, **changes))


def _inputs(args, config):
    """(task-language data, cache, dataset, the generator's TL targets, the translator's features of every cached
    sentence, the instruction sets by name, the development sentences)."""
    cache = build_cache(config.env, config.encoder, progress=False)
    dataset = TaskDataset.load(args.run / "oracle" / "dataset")
    data = make_task_language_data(dataset, cache, config.sentence_readout)
    generator = load_tree(args.run / "talar" / "task_language" / "params.msgpack")["generator"]
    generate = jax.jit(jax.vmap(make_generate_task_language(config.talar), in_axes=(0, None, None)))
    targets = jnp.asarray(generate(generator, data.states, data.final_states), jnp.float32)
    encoder = load_encoder(config.encoder)
    features = readout_features(cache, translator_readout(config), encoder)
    train_rows = load_instructions(config.env, "train").sentence_ids
    test_rows = load_instructions(config.env, "test").sentence_ids
    dev_sentences, dev_goals = load_user_instructions(args.development, config.env)
    dev_features = cached_sentence_features(encoder, dev_sentences, translator_readout(config))
    sets = {
        "train": (features[train_rows], cache.goal_ids[train_rows]),
        "test": (features[test_rows], cache.goal_ids[test_rows]),
        "development": (dev_features, np.asarray(dev_goals)),
    }
    return data, cache, dataset, targets, features, sets, dev_sentences


def _translators(args, talar, count: int, edits: str, seed_keys, targets, train_data) -> tuple[dict, float]:
    """(seed-stacked translator params, fit seconds): the run's own translator for the recipe's paper setting, one an
    earlier call saved, or a new fit from the run's seed keys (saved for the next call)."""
    rate = f"-lr{args.learning_rate:g}" if args.learning_rate else ""
    saved = (
        args.run / "translator-robustness" / f"paraphrases{count}{edits}-steps{talar.translator_steps}{rate}.msgpack"
    )
    own = args.run / "talar" / "translator" / "params.msgpack"
    recipe_setting = count == 0 and args.steps is None and args.learning_rate is None and args.tokens is None
    if recipe_setting and own.is_file():  # the run's own translator (the same training)
        return load_tree(own), 0.0
    if saved.is_file():  # trained by an earlier call (e.g. before the run's policy had finished)
        return load_tree(saved), 0.0
    timings: dict[str, float] = {}
    params, _ = fit_seeds(
        make_train_translator(talar), seed_keys, targets, train_data, in_axes=(0, None), progress=False, timings=timings
    )
    saved.parent.mkdir(parents=True, exist_ok=True)
    save_tree(saved, params)
    return params, timings["run_s"]


def _seed_scores(args, translate, params, seed: int, sets, num_dev: int):
    """One seed's TL agreement per set, its development misses, and (with ``--episodes``) the run's policy's success
    on this translator's codes."""
    seed_params = jax.tree.map(lambda x: x[seed : seed + 1], params)
    train_codes = np.asarray(translate(seed_params, sets["train"][0]))[0].round()
    goal_codes = {}
    for goal in np.unique(sets["train"][1]):
        rows, counts = np.unique(train_codes[sets["train"][1] == goal], axis=0, return_counts=True)
        goal_codes[int(goal)] = rows[np.argmax(counts)]
    agreements, misses = {}, np.zeros(num_dev, int)
    for name, (x, goals) in sets.items():
        codes = np.asarray(translate(seed_params, x))[0].round()
        agreements[name] = agreement(codes, goals, goal_codes)
        if name == "development":
            misses += [not np.array_equal(c, goal_codes.get(int(g))) for c, g in zip(codes, goals)]
    if not args.episodes:
        return agreements, misses, {}
    # the run's policy, fed this translator's codes: valid while the goals keep the run's codes
    agent = load_agent(args.run / "talar", seed=seed)
    same = all(np.array_equal(agent.goal_code(g).round(), c) for g, c in goal_codes.items())
    swapped = SwappedTranslator(agent, lambda x, p=seed_params: np.asarray(translate(p, x))[0].round(), goal_codes)
    named = {n: (x, g, None) for n, (x, g) in sets.items()}
    named["yours"] = named.pop("development")
    rates = evaluate_seed(swapped, named, args.episodes, rng_seed=0)
    return agreements, misses, {**{name: rate["success"] for name, rate in rates.items()}, "goal_codes_unchanged": same}


def _print_variant(args, count: int, result: dict, success: dict, misses: np.ndarray, dev_sentences) -> None:
    per_seed, quality = result["per_seed"], result["quality_per_seed"]
    line = ", ".join(f"{n} {100 * np.mean(v):.1f} ± {100 * np.std(v):.1f}" for n, v in per_seed.items())
    print(f"paraphrases {count}: TL agreement {line}  ({result['total_s']:.0f} s)", flush=True)
    line = ", ".join(f"{k} {np.mean(v):.3f}" for k, v in quality.items())
    print(f"    report quality: {line}; fit {result['translator_fit_s']:.0f} s without compile", flush=True)
    if success:
        rates = {n: v for n, v in success.items() if n != "goal_codes_unchanged"}
        line = ", ".join(f"{n} {100 * np.mean(v):.1f} ± {100 * np.std(v):.1f}" for n, v in rates.items())
        unchanged = success["goal_codes_unchanged"]
        print(f"    success with the run's policy: {line} (goal codes unchanged per seed: {unchanged})")
    worst = np.argsort(-misses, kind="stable")[: args.show_failures]
    for row in worst[misses[worst] > 0]:
        print(f"    {misses[row]}/{args.seeds} seeds miss: {dev_sentences[row]!r}", flush=True)


def _variant(args, config, count: int, inputs) -> tuple[str, dict]:
    """Trains (or reuses) the translators with ``count`` paraphrases and scores them; prints the result and returns
    (its label, the result)."""
    data, cache, dataset, targets, features, sets, dev_sentences = inputs
    talar = dataclasses.replace(
        config.talar,
        translator_paraphrases=count,
        paraphrase_probability=args.probability,
        paraphrase_unknown_words=args.unknown_words,
        paraphrase_front_phrases=args.front_phrases,
    )
    start = time.perf_counter()
    train_data = paraphrased_data(
        MethodContext(dataclasses.replace(config, talar=talar), "", data, cache, dataset, None)
    )
    encode_s = time.perf_counter() - start
    edits = "".join(
        suffix
        for suffix, on in (
            ("-unknown", talar.paraphrase_unknown_words),
            ("-front", talar.paraphrase_front_phrases),
            ("-tokens", talar.translator_tokens),
        )
        if on
    )
    seed_keys = stage_seed_keys(config.seed, "talar/translator", args.seeds)
    params, fit_s = _translators(args, talar, count, edits, seed_keys, targets, train_data)
    translate = jax.jit(jax.vmap(make_translate(talar), in_axes=(0, None)))
    quality = [
        task_language_quality(t, cache.goal_ids, cache.is_train) for t in np.asarray(translate(params, features))
    ]
    per_seed, misses, success = {name: [] for name in sets}, np.zeros(len(dev_sentences), int), {}
    for seed in range(args.seeds):
        agreements, seed_misses, seed_success = _seed_scores(args, translate, params, seed, sets, len(dev_sentences))
        misses += seed_misses
        for name, value in agreements.items():
            per_seed[name].append(value)
        for name, value in seed_success.items():
            success.setdefault(name, []).append(value)
    result = {
        "per_seed": per_seed,
        "success_per_seed": success,
        "quality_per_seed": {k: [round(q[k], 3) for q in quality] for k in quality[0]},
        "translator_fit_s": fit_s,
        "encode_s": encode_s,
        "total_s": time.perf_counter() - start,
    }
    _print_variant(args, count, result, success, misses, dev_sentences)
    result["development_misses"] = {dev_sentences[r]: int(misses[r]) for r in np.flatnonzero(misses)}
    return f"{count}{edits}", result


def run_command(argv: list[str] | None = None) -> None:
    runtime.start()
    args = _parser().parse_args(argv)
    check_outputs((args.json, "--json", "file"), (args.run / "translator-robustness", "RUN", "folder"))
    config = _config(args)
    inputs = _inputs(args, config)
    results = dict(_variant(args, config, count, inputs) for count in args.paraphrases)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "run": str(args.run),
            "env": args.env,
            "probability": args.probability,
            "translator_steps": config.talar.translator_steps,
            "results": results,
        }
        args.json.write_text(json.dumps(payload, indent=2))


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
