"""The baselines that feed a sentence embedding to the policy through a trained encoding layer: BERT-binary /
-continuous, their behaviour-cloned (pre-trained) variants, the aligned ones whose layer has the TL generator's
architecture (Appendix E.3), and the fine-tuned ones whose BERT the policy's loss trains too (Appendix E.5)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from experiments.config import ExperimentConfig
from experiments.methods.base import FIT_CHECKPOINT, Method, MethodContext, MethodSetup
from talar_jax.baselines import EncodingLayerConditioner, FinetunedBertConditioner, make_behaviour_cloning
from talar_jax.checkpoint import load_tree, save_tree
from talar_jax.conditioning import split_instruction_ids
from talar_jax.encodings import EncodingArtifact
from talar_jax.language import load_encoder
from talar_jax.optim import fit_seeds
from talar_jax.stages import run_stage, stable_hash


def behaviour_cloning_key(config: ExperimentConfig, name: str, upstream_key: str, cache_key: str) -> str:
    """Pre-trained BERT-*: dataset, encoding size, readout, the policy network, BC Adam settings, seeds."""
    t = config.talar
    return stable_hash(
        name,
        upstream_key,
        cache_key,
        t.spec.size,
        config.sentence_readout,
        config.ifp.hidden_sizes,
        config.ifp.normalize_observations,
        t.batch_size,
        t.bc_learning_rate,
        t.bc_steps,
        config.seeds,
        config.seed,
    )


def _behaviour_cloning(ctx: MethodContext, conditioner, stage_name: str, key: str) -> MethodSetup:
    """Pre-trained BERT-*: the encoding layer and policy behaviour-cloned on the task dataset before PPO."""
    config, name = ctx.config, ctx.config.method

    def bc_body(stage_dir: Path) -> dict[str, Any]:
        t = config.talar
        fit = make_behaviour_cloning(
            ctx.env,
            conditioner,
            ctx.dataset,
            config.ifp.hidden_sizes,
            t.batch_size,
            t.bc_learning_rate,
            t.bc_steps,
            normalize_observations=config.ifp.normalize_observations,
        )
        label = f"{name}/behaviour cloning"
        params, losses = fit_seeds(
            fit, ctx.seed_keys(name), label=label, progress=config.progress, checkpoint=stage_dir / FIT_CHECKPOINT
        )
        save_tree(stage_dir / "params.msgpack", params)
        return {"bc_nll_end": losses[:, -100:].mean(1).tolist()}

    stage = run_stage(config.out, stage_name, key, bc_body, reuse_from=config.reuse_stages)
    params = load_tree(stage.path / "params.msgpack")
    return MethodSetup(conditioner, params, stage.key, None, ctx.named(stage))


def encoding_layer_method(name: str, label: str, binary: bool, pretrained: bool = False, aligned: bool = False):
    """BERT-binary / -continuous (``pretrained``: behaviour-cloned first; ``aligned``: the layer has the TL
    generator's architecture)."""

    def stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
        if pretrained:
            return {f"{name}/behaviour_cloning": behaviour_cloning_key(config, name, upstream_key, cache_key)}
        if aligned:  # no stage of its own: the encoding's inputs, with the generator's architecture
            t = config.talar
            return {name: stable_hash(name, cache_key, config.sentence_readout, t.spec, t.generator_hidden)}
        return {name: stable_hash(name, cache_key, config.sentence_readout, config.talar.spec.size)}

    def setup(ctx: MethodContext) -> MethodSetup:
        config = ctx.config
        features = ctx.data.sentence_embeddings  # the experiment's sentence readout (on device already)
        architecture = (config.talar.spec, config.talar.generator_hidden) if aligned else None
        conditioner = EncodingLayerConditioner(features, ctx.lookups(), config.talar.spec.size, binary, architecture)
        ((stage_name, key),) = ctx.stage_keys().items()
        if pretrained:
            return _behaviour_cloning(ctx, conditioner, stage_name, key)
        return MethodSetup(conditioner, None, key, None)

    def encoding(config: ExperimentConfig, _num_goals: int) -> EncodingArtifact:
        t = config.talar
        if aligned:
            return EncodingArtifact.aligned_encoding_layer(t.spec, t.generator_hidden, binary, config.sentence_readout)
        return EncodingArtifact.nl_encoding_layer(t.spec.size, binary, config.sentence_readout)

    return Method(name=name, label=label, stage_keys=stage_keys, setup=setup, encoding=encoding)


def finetuned_method(name: str, label: str, binary: bool) -> Method:
    """Appendix E.5: BERT-binary / -continuous with BERT trained by the policy's loss (``FinetunedBertConditioner``);
    the encoding layer reads the pooled sentence embedding (the paper's BERT readout: a prefix readout would need a
    BERT pass per prefix inside the loop)."""

    def stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
        t = config.talar  # no stage of its own: the encoding's inputs, BERT trained from the encoder's weights
        return {name: stable_hash(name, cache_key, t.spec.size, t.finetuned_bert_first_layer)}

    def setup(ctx: MethodContext) -> MethodSetup:
        config, cache = ctx.config, ctx.cache
        lookups = ctx.lookups()
        conditioner = FinetunedBertConditioner.from_cache(
            load_encoder(config.encoder),
            cache,
            lookups,
            config.talar.spec.size,
            binary,
            config.talar.finetuned_bert_first_layer,
            split_instruction_ids(lookups, "train"),
        )
        ((_, key),) = ctx.stage_keys().items()
        return MethodSetup(conditioner, None, key, None)

    reason = "a fine-tuned BERT run trains the encoder's weights with the policy, which an agent does not load"
    return Method(
        name, label, stage_keys, setup, lambda config, _: EncodingArtifact.unreadable(reason, config.sentence_readout)
    )


BERT_METHODS = (
    encoding_layer_method("bert-binary", "BERT-binary", binary=True),
    encoding_layer_method("bert-continuous", "BERT-continuous", binary=False),
    encoding_layer_method("pretrained-bert-binary", "Pre-trained BERT-binary", binary=True, pretrained=True),
    encoding_layer_method("pretrained-bert-continuous", "Pre-trained BERT-continuous", binary=False, pretrained=True),
)
ALIGNED_METHODS = (
    encoding_layer_method("aligned-bert-binary", "Aligned BERT-binary", binary=True, aligned=True),
    encoding_layer_method("aligned-bert-continuous", "Aligned BERT-continuous", binary=False, aligned=True),
)
FINETUNED_METHODS = (
    finetuned_method("finetuned-bert-binary", "Fine-tuned BERT-binary", binary=True),
    finetuned_method("finetuned-bert-continuous", "Fine-tuned BERT-continuous", binary=False),
)
