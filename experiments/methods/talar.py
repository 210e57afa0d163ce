"""TALAR (Algorithms 1-2: referential game, then translator) and end-to-end TALAR (Appendix E.6)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from experiments.config import ExperimentConfig
from experiments.methods.base import FIT_CHECKPOINT, Method, MethodContext, MethodSetup, translator_readout
from experiments.methods.translation import table_setup, translator_encoding, translator_key, translator_stage
from talar_jax.checkpoint import load_tree, save_tree
from talar_jax.optim import fit_seeds
from talar_jax.stages import run_stage, stable_hash
from talar_jax.talar import (
    make_generate_task_language,
    make_train_end_to_end,
    make_train_task_language,
    make_translate,
    prepare_referential_data,
    task_language_quality,
    trim_token_padding,
)


def referential_game_key(config: ExperimentConfig, upstream_key: str, cache_key: str) -> str:
    """TALAR's referential game (generator + receiver): dataset, cache, RG settings, seeds."""
    fields = config.talar.referential_game_fields()
    return stable_hash("task_language", upstream_key, cache_key, fields, config.seeds, config.seed)


def talar_stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    rg = referential_game_key(config, upstream_key, cache_key)
    return {"talar/task_language": rg, "talar/translator": translator_key(config, rg, "translator")}


def _fit_summary(losses: np.ndarray, name: str, first: bool = False) -> dict[str, list[float]]:
    """The mean loss over the first / last 5 % of a fit's steps, per seed."""
    window = max(1, losses.shape[1] // 20)
    start = {f"{name}_start": losses[:, :window].mean(1).tolist()} if first else {}
    return {**start, f"{name}_end": losses[:, -window:].mean(1).tolist()}


def setup_talar(ctx: MethodContext) -> MethodSetup:
    """Referential game (Algorithm 1), then the translator to the frozen generator's TL (Algorithm 2)."""
    config, cache, data = ctx.config, ctx.cache, ctx.data
    keys = ctx.stage_keys()

    def rg_body(stage_dir: Path) -> dict[str, Any]:
        fit = make_train_task_language(config.talar, cache.vocab_size, cache.max_tokens)
        label, timings = "talar/referential game", {}
        params, losses = fit_seeds(
            fit,
            ctx.seed_keys("task_language"),
            prepare_referential_data(config.talar, data),
            label=label,
            progress=config.progress,
            timings=timings,
            checkpoint=stage_dir / FIT_CHECKPOINT,
        )
        save_tree(stage_dir / "params.msgpack", params)
        np.save(stage_dir / "losses.npy", losses)
        return {**_fit_summary(losses, "rg_loss", first=True), **timings}

    rg = run_stage(
        config.out, "talar/task_language", keys["talar/task_language"], rg_body, reuse_from=config.reuse_stages
    )

    def targets(stage_dir: Path) -> jax.Array:
        generator_params = load_tree(rg.path / "params.msgpack")["generator"]
        generate = jax.vmap(make_generate_task_language(config.talar), in_axes=(0, None, None))
        return jax.jit(generate)(generator_params, data.states, data.final_states)

    translator = translator_stage(ctx, "talar/translator", keys["talar/translator"], config.talar.spec, targets)
    return table_setup(ctx, rg, translator)


def end_to_end_stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    t = config.talar
    fields = (t.referential_game_fields(), t.translator_hidden, translator_readout(config), config.seeds, config.seed)
    return {"end-to-end/joint": stable_hash("end-to-end", upstream_key, cache_key, *fields)}


def setup_end_to_end(ctx: MethodContext) -> MethodSetup:
    """End-to-end TALAR (Appendix E.6): generator, receiver and translator trained jointly in one stage."""
    config, cache, data = ctx.config, ctx.cache, ctx.translator_data()
    ((stage_name, key),) = ctx.stage_keys().items()

    def body(stage_dir: Path) -> dict[str, Any]:
        fit, timings = make_train_end_to_end(config.talar, cache.vocab_size, cache.max_tokens), {}
        params, losses = fit_seeds(
            fit,
            ctx.seed_keys("end-to-end"),
            prepare_referential_data(config.talar, trim_token_padding(data)),
            label="end-to-end/joint",
            progress=config.progress,
            timings=timings,
            checkpoint=stage_dir / FIT_CHECKPOINT,
        )
        translate = jax.jit(jax.vmap(make_translate(config.talar), in_axes=(0, None)))
        tables = np.asarray(translate(params["translator"], data.sentence_embeddings))
        save_tree(stage_dir / "params.msgpack", params)
        np.save(stage_dir / "tables.npy", tables)
        quality = [task_language_quality(t, cache.goal_ids, cache.is_train) for t in tables]
        return {
            **_fit_summary(losses, "joint_loss"),
            "tl_quality": {k: [q[k] for q in quality] for k in quality[0]},
            **timings,
        }

    return table_setup(ctx, run_stage(config.out, stage_name, key, body, reuse_from=config.reuse_stages))


TALAR = Method(
    name="talar",
    label="TALAR",
    stage_keys=talar_stage_keys,
    setup=setup_talar,
    encoding=lambda config, _: translator_encoding(config, config.talar.spec, "talar/translator/params.msgpack"),
)
END_TO_END = Method(
    name="end-to-end",
    label="End-to-end TALAR",
    stage_keys=end_to_end_stage_keys,
    setup=setup_end_to_end,
    encoding=lambda config, _: translator_encoding(
        config, config.talar.spec, "end-to-end/joint/params.msgpack", entry="translator"
    ),
)
