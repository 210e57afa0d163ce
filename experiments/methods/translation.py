"""Pieces the translator-based methods share: the translator stage, its paraphrase-augmented data, frozen tables."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from experiments.methods.base import FIT_CHECKPOINT, MethodContext, MethodSetup, translator_readout
from talar_jax.checkpoint import save_tree
from talar_jax.conditioning import InstructionTableConditioner
from talar_jax.encodings import EncodingArtifact
from talar_jax.language import (
    DEVELOPMENT_FILE,
    cached_sentence_features,
    load_encoder,
    load_user_instructions,
    paraphrase_variants,
)
from talar_jax.optim import fit_seeds
from talar_jax.stages import StageResult, run_stage, stable_hash
from talar_jax.talar import (
    TaskLanguageData,
    make_train_translator,
    make_translate,
    task_language_quality,
    trim_token_padding,
    with_paraphrases,
)
from talar_jax.task_language import TaskLanguageSpec


def table_setup(ctx: MethodContext, *stages: StageResult) -> MethodSetup:
    """A frozen per-seed table from the last stage's ``tables.npy``; all ``stages`` reported."""
    tables = np.asarray(np.load(stages[-1].path / "tables.npy"), np.float32)
    return frozen_table_setup(ctx, tables, stages[-1].key, stages)


def frozen_table_setup(ctx: MethodContext, tables: np.ndarray, key: str, stages=()) -> MethodSetup:
    """The policy conditioned on a fixed (seeds, S, size) table of instruction codes."""
    conditioner = InstructionTableConditioner(tables[0], ctx.lookups(), trainable=False)
    return MethodSetup(conditioner, {"conditioner": {"table": tables}}, key, tables, ctx.named(*stages))


def translator_stage(ctx: MethodContext, name: str, key: str, spec: TaskLanguageSpec, targets_fn) -> StageResult:
    """Trains one translator per seed to ``targets_fn(stage_dir) -> (seeds, N, |L|)``; saves translated tables."""
    config, cache = ctx.config, ctx.cache

    def body(stage_dir: Path) -> dict[str, Any]:
        targets = jnp.asarray(targets_fn(stage_dir), jnp.float32)
        data = ctx.translator_data()
        fit, timings = make_train_translator(config.talar, spec), {}
        start = time.perf_counter()
        train_data = trim_token_padding(paraphrased_data(ctx, data))  # paraphrases: encoded once per machine
        paraphrase_s = time.perf_counter() - start
        params, losses = fit_seeds(
            fit,
            ctx.seed_keys(name),
            targets,
            train_data,
            in_axes=(0, None),
            label=name,
            progress=config.progress,
            timings=timings,
            checkpoint=stage_dir / FIT_CHECKPOINT,
        )
        translate = jax.jit(jax.vmap(make_translate(config.talar, spec), in_axes=(0, None)))
        tables = np.asarray(translate(params, data.sentence_embeddings))
        save_tree(stage_dir / "params.msgpack", params)
        np.save(stage_dir / "tables.npy", tables)
        quality = [task_language_quality(t, cache.goal_ids, cache.is_train) for t in tables]
        return {
            "translator_loss_end": losses[:, -max(1, losses.shape[1] // 20) :].mean(1).tolist(),
            "tl_quality": {k: [q[k] for q in quality] for k in quality[0]},
            "distinct_target_codes": [len(np.unique(np.asarray(t).round(), axis=0)) for t in targets],
            **({"paraphrase_features_s": paraphrase_s} if config.talar.translator_paraphrases else {}),
            **timings,
        }

    return run_stage(config.out, name, key, body, reuse_from=config.reuse_stages)


def paraphrased_data(ctx: MethodContext, data: TaskLanguageData | None = None) -> TaskLanguageData:
    """The translator's data (``data``, default ``ctx.translator_data()``), plus ``config.talar.translator_paraphrases``
    paraphrases of each training instruction the task dataset uses (never a test sentence), encoded once like the
    cache's own sentences."""
    config, cache = ctx.config, ctx.cache
    data = ctx.translator_data() if data is None else data
    count = config.talar.translator_paraphrases
    if not count:
        return data
    rows = np.asarray(data.dataset_sentences)
    if not cache.is_train[rows].all():
        raise ValueError("the task dataset uses test instructions; paraphrases are made from training ones only")
    held_out = [s for s, train in zip(cache.sentences, cache.is_train) if not train]
    with contextlib.suppress(ValueError):  # an env without development phrasings has none to keep out
        held_out += load_user_instructions(DEVELOPMENT_FILE, config.env)[0]
    encoder = load_encoder(config.encoder)
    variants = paraphrase_variants(
        [cache.sentences[r] for r in rows],
        cache.goal_ids[rows],
        count,
        seed=config.talar.paraphrase_seed,
        exclude=held_out,
        unknown_words=encoder.whole_words() if config.talar.paraphrase_unknown_words else (),
        front_phrases=config.talar.paraphrase_front_phrases,
    )
    sentences = [v for per_sentence in variants for v in per_sentence]
    features = cached_sentence_features(encoder, sentences, translator_readout(config), progress=config.progress)
    return with_paraphrases(data, features, np.repeat(rows, count))


def translator_key(config, targets_key: str, name: str) -> str:
    """A translator to the targets of the stage keyed ``targets_key``: its settings and the sentence readout."""
    return stable_hash(
        name, targets_key, config.talar.translator_fields(), config.sentence_readout, config.seeds, config.seed
    )


def translator_encoding(config, spec: TaskLanguageSpec, params_path: str, entry: str | None = None):
    """How an agent reads a sentence through a translator: the spec, hidden sizes and readout the stage trained."""
    return EncodingArtifact.translator(
        spec, config.talar.translator_hidden, translator_readout(config), params_path, entry=entry
    )
