"""Baselines whose translator learns a code other than TALAR's: Handcrafted (the goal's one-hot, Appendix E.7), GLA
(a latent-action auto-encoder's binary code) and One-hot (a code per instruction, no translator)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from experiments.config import ExperimentConfig
from experiments.methods.base import FIT_CHECKPOINT, Method, MethodContext, MethodSetup
from experiments.methods.translation import (
    frozen_table_setup,
    table_setup,
    translator_encoding,
    translator_key,
    translator_stage,
)
from talar_jax.baselines import goal_one_hot, make_gla_codes, make_train_gla, one_hot_table
from talar_jax.checkpoint import load_tree, save_tree
from talar_jax.encodings import EncodingArtifact
from talar_jax.optim import fit_seeds
from talar_jax.stages import run_stage, stable_hash
from talar_jax.task_language import TaskLanguageSpec


def handcrafted_spec(num_goals: int) -> TaskLanguageSpec:
    """One argument network over the goals: a one-hot of the goal."""
    return TaskLanguageSpec(num_predicates=0, num_arguments=1, arg_size=num_goals)


def handcrafted_stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    targets = stable_hash("goal one-hot", upstream_key, cache_key)
    return {"handcrafted/translator": translator_key(config, targets, "handcrafted")}


def setup_handcrafted(ctx: MethodContext) -> MethodSetup:
    """Appendix E.7: the translator trained to a one-hot of the goal instead of the generator's TL."""
    goals = goal_one_hot(ctx.dataset.goal_ids, ctx.cache.num_goals)
    key = ctx.stage_keys()["handcrafted/translator"]
    spec = handcrafted_spec(ctx.cache.num_goals)
    stage = translator_stage(
        ctx, "handcrafted/translator", key, spec, lambda _: np.broadcast_to(goals, (ctx.seeds, *goals.shape))
    )
    return table_setup(ctx, stage)


def gla_key(config: ExperimentConfig, upstream_key: str) -> str:
    """GLA's latent-action auto-encoder: dataset, code size, its Adam settings, seeds."""
    t = config.talar
    return stable_hash(
        "gla", upstream_key, t.spec.size, t.rg_steps, t.batch_size, t.rg_learning_rate, config.seeds, config.seed
    )


def gla_stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    gla = gla_key(config, upstream_key)
    return {"gla/autoencoder": gla, "gla/translator": translator_key(config, gla, "gla_translator")}


def gla_spec(config: ExperimentConfig) -> TaskLanguageSpec:
    """|L_T| independent bits: the latent code's size is the TL's."""
    return TaskLanguageSpec(num_predicates=config.talar.spec.size, num_arguments=0)


def setup_gla(ctx: MethodContext) -> MethodSetup:
    """GLA: a latent-action auto-encoder of (s, s'), then the translator to its binary latent code (|L_T| bits)."""
    config, data = ctx.config, ctx.data
    size, obs = config.talar.spec.size, data.states.shape[-1]
    keys = ctx.stage_keys()

    def gla_body(stage_dir: Path) -> dict[str, Any]:
        fit = make_train_gla(size, obs, config.talar.rg_steps, config.talar.batch_size, config.talar.rg_learning_rate)
        params, losses = fit_seeds(
            fit,
            ctx.seed_keys("gla"),
            data.states,
            data.final_states,
            label="gla/autoencoder",
            progress=config.progress,
            checkpoint=stage_dir / FIT_CHECKPOINT,
        )
        save_tree(stage_dir / "params.msgpack", params)
        return {"reconstruction_mse_end": losses[:, -100:].mean(1).tolist()}

    gla = run_stage(config.out, "gla/autoencoder", keys["gla/autoencoder"], gla_body, reuse_from=config.reuse_stages)

    def targets(stage_dir: Path) -> jax.Array:
        codes = jax.vmap(make_gla_codes(size, obs), in_axes=(0, None, None))
        return jax.jit(codes)(load_tree(gla.path / "params.msgpack"), data.states, data.final_states)

    stage = translator_stage(ctx, "gla/translator", keys["gla/translator"], gla_spec(config), targets)
    return table_setup(ctx, gla, stage)


def setup_onehot(ctx: MethodContext) -> MethodSetup:
    """One-hot: a unique one-hot per instruction over train and test instructions together."""
    table = one_hot_table(len(ctx.cache.sentences))
    tables = np.broadcast_to(np.asarray(table, np.float32), (ctx.seeds, *table.shape))
    return frozen_table_setup(ctx, tables, ctx.stage_keys()["onehot"])


HANDCRAFTED = Method(
    name="handcrafted",
    label="Handcrafted",
    stage_keys=handcrafted_stage_keys,
    setup=setup_handcrafted,
    encoding=lambda config, num_goals: translator_encoding(
        config, handcrafted_spec(num_goals), "handcrafted/translator/params.msgpack"
    ),
)
GLA = Method(
    name="gla",
    label="GLA",
    stage_keys=gla_stage_keys,
    setup=setup_gla,
    encoding=lambda config, _: translator_encoding(config, gla_spec(config), "gla/translator/params.msgpack"),
)
ONEHOT = Method(
    name="onehot",
    label="One-hot",
    stage_keys=lambda config, upstream_key, cache_key: {"onehot": stable_hash("onehot", cache_key)},
    setup=setup_onehot,
    encoding=lambda config, _: EncodingArtifact.unreadable(
        "a One-hot run gives every training sentence its own code and has no way to read a new sentence; "
        "load a TALAR, end-to-end TALAR, Handcrafted, GLA or BERT-* run",
        config.sentence_readout,
    ),
)
