"""How each method turns instructions into the policy's conditioning vector (TALAR and the paper's baselines).

Each ``setup_<method>`` runs the method's own cached stages and returns a ``MethodSetup``: the conditioner the
IFP's PPO uses, seed-stacked initial parameters (frozen tables, behaviour-cloned weights), the key of
everything upstream, and per-seed instruction encodings for the t-SNE figure.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from talar_jax.baselines import (
    EncodingLayerConditioner,
    FinetunedBertConditioner,
    goal_one_hot,
    make_behaviour_cloning,
    make_gla_codes,
    make_train_gla,
    one_hot_table,
)
from talar_jax.checkpoint import load_tree, save_tree
from talar_jax.conditioning import Conditioner, InstructionTableConditioner, split_instruction_ids
from talar_jax.dataset import TaskDataset
from talar_jax.language import (
    DEVELOPMENT_FILE,
    TOKEN_READOUT,
    EmbeddingCache,
    cached_sentence_features,
    load_encoder,
    load_instructions,
    load_user_instructions,
    paraphrase_variants,
    readout_features,
)
from talar_jax.optim import fit_seeds
from talar_jax.sharding import shard_seeds
from talar_jax.stages import StageResult, run_stage, stable_hash
from talar_jax.talar import (
    TaskLanguageData,
    make_generate_task_language,
    make_train_end_to_end,
    make_train_task_language,
    make_train_translator,
    make_translate,
    prepare_referential_data,
    task_language_quality,
    trim_token_padding,
    with_paraphrases,
)
from talar_jax.task_language import TaskLanguageSpec

if TYPE_CHECKING:
    from experiments.pipeline import ExperimentConfig


@dataclasses.dataclass(frozen=True)
class MethodSetup:
    """What the IFP stage needs from a method."""

    conditioner: Conditioner
    initial_params: dict[str, Any] | None
    key: str
    encodings: np.ndarray | None  # (seeds, S, size) instruction encodings (t-SNE), None when trained by RL
    stages: dict[str, StageResult] = dataclasses.field(default_factory=dict)  # the method's own stages, by name

    @property
    def summary(self) -> dict[str, Any]:
        """The summaries of the method's stages, merged in order."""
        return {k: v for stage in self.stages.values() for k, v in stage.summary.items()}


def translator_readout(config: ExperimentConfig) -> str:
    """What the run's translators read of a sentence: the token states with ``talar.translator_tokens``, else the
    experiment's ``sentence_readout`` (which the NL-encoding baselines always read)."""
    return TOKEN_READOUT if config.talar.translator_tokens else config.sentence_readout


def stage_seed_keys(seed: int, stage: str, seeds: int) -> jax.Array:
    """(seeds,) keys of a stage of the run with base seed ``seed``, stable across processes (crc32 of the stage's
    name, not Python's hash): what a script retraining a stage's fit needs to match the run."""
    key = jax.random.fold_in(jax.random.PRNGKey(seed), zlib.crc32(stage.encode()))
    return jax.random.split(key, seeds)


@dataclasses.dataclass(frozen=True)
class MethodContext:
    """Inputs shared by every method of one experiment."""

    config: ExperimentConfig  # resolved
    upstream_key: str  # key of the oracle/dataset stage
    data: TaskLanguageData
    cache: EmbeddingCache
    dataset: TaskDataset
    env: Any

    @property
    def seeds(self) -> int:
        return self.config.seeds

    def named(self, *stages: StageResult) -> dict[str, StageResult]:
        """Stages by their folder relative to ``out`` (the keys of ``stage_seconds``)."""
        return {stage.path.relative_to(self.config.out).as_posix(): stage for stage in stages}

    def seed_keys(self, stage: str) -> jax.Array:
        """(seeds,) keys of a stage (``stage_seed_keys``), sharded over the devices."""
        return shard_seeds(stage_seed_keys(self.config.seed, stage, self.seeds), self.seeds)

    def translator_data(self) -> TaskLanguageData:
        """``data`` with the translator's readout of every cached sentence (``translator_readout``): the same
        arrays unless the translator reads token states."""
        readout = translator_readout(self.config)
        if readout == self.config.sentence_readout:
            return self.data
        encoder = load_encoder(self.config.encoder)
        features = readout_features(self.cache, readout, encoder, progress=self.config.progress)
        return self.data._replace(sentence_embeddings=jnp.asarray(features, jnp.float32))

    def lookups(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """split -> (goal -> cache rows of its instructions, counts); CLEVR training may keep only k patterns."""
        lookups = {}
        for split in ("train", "test"):
            patterns = self.config.num_patterns if split == "train" else None
            instructions = load_instructions(self.config.env, split, num_patterns=patterns)
            lookups[split] = (instructions.goal_cache_rows(), instructions.goal_sentence_counts)
        return lookups


FIT_CHECKPOINT = "checkpoints/fit.msgpack"
"""Where a supervised stage's fit saves its state after every piece (resumed while the stage's key holds)."""


# ------------------------------------------------------------------------------------------------
# Stage keys: each from the upstream keys and exactly the settings the stage reads (tests/test_stage_keys.py)
# ------------------------------------------------------------------------------------------------
def referential_game_key(config: ExperimentConfig, upstream_key: str, cache_key: str) -> str:
    """TALAR's referential game (generator + receiver): dataset, cache, RG settings, seeds."""
    fields = config.talar.referential_game_fields()
    return stable_hash("task_language", upstream_key, cache_key, fields, config.seeds, config.seed)


def translator_key(config: ExperimentConfig, targets_key: str, name: str) -> str:
    """A translator to the targets of the stage keyed ``targets_key``: its settings and the sentence readout."""
    return stable_hash(
        name, targets_key, config.talar.translator_fields(), config.sentence_readout, config.seeds, config.seed
    )


def gla_key(config: ExperimentConfig, upstream_key: str) -> str:
    """GLA's latent-action auto-encoder: dataset, code size, its Adam settings, seeds."""
    t = config.talar
    return stable_hash(
        "gla", upstream_key, t.spec.size, t.rg_steps, t.batch_size, t.rg_learning_rate, config.seeds, config.seed
    )


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


def method_stage_keys(config: ExperimentConfig, upstream_key: str, cache_key: str) -> dict[str, str]:
    """Stage folder -> key of every stage of ``config.method``; the last entry is what the IFP builds on."""
    method = config.method
    if method == "talar":
        rg = referential_game_key(config, upstream_key, cache_key)
        return {"talar/task_language": rg, "talar/translator": translator_key(config, rg, "translator")}
    if method == "handcrafted":
        targets = stable_hash("goal one-hot", upstream_key, cache_key)
        return {"handcrafted/translator": translator_key(config, targets, "handcrafted")}
    if method == "gla":
        gla = gla_key(config, upstream_key)
        return {"gla/autoencoder": gla, "gla/translator": translator_key(config, gla, "gla_translator")}
    if method == "onehot":
        return {"onehot": stable_hash("onehot", cache_key)}
    if method == "end-to-end":
        t = config.talar
        fields = (
            t.referential_game_fields(),
            t.translator_hidden,
            translator_readout(config),
            config.seeds,
            config.seed,
        )
        return {"end-to-end/joint": stable_hash("end-to-end", upstream_key, cache_key, *fields)}
    if method.startswith("pretrained-"):
        return {f"{method}/behaviour_cloning": behaviour_cloning_key(config, method, upstream_key, cache_key)}
    if method.startswith("bert-"):  # no stage of its own: the encoding's inputs
        return {method: stable_hash(method, cache_key, config.sentence_readout, config.talar.spec.size)}
    if method.startswith("finetuned-"):  # the same, with BERT trained from the encoder's weights
        t = config.talar
        return {method: stable_hash(method, cache_key, t.spec.size, t.finetuned_bert_first_layer)}
    if method.startswith("aligned-"):  # the same, with the generator's architecture
        t = config.talar
        return {method: stable_hash(method, cache_key, config.sentence_readout, t.spec, t.generator_hidden)}
    raise ValueError(f"unknown method {method!r}; valid methods: {', '.join(METHODS)}")


def _table_setup(ctx: MethodContext, *stages: StageResult) -> MethodSetup:
    """A frozen per-seed table from the last stage's ``tables.npy``; all ``stages`` reported."""
    tables = np.asarray(np.load(stages[-1].path / "tables.npy"), np.float32)
    return _frozen_table_setup(ctx, tables, stages[-1].key, stages)


def _frozen_table_setup(ctx: MethodContext, tables: np.ndarray, key: str, stages=()) -> MethodSetup:
    conditioner = InstructionTableConditioner(tables[0], ctx.lookups(), trainable=False)
    return MethodSetup(conditioner, {"conditioner": {"table": tables}}, key, tables, ctx.named(*stages))


def _translator_stage(ctx: MethodContext, name: str, key: str, spec: TaskLanguageSpec, targets_fn) -> StageResult:
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


def setup_talar(ctx: MethodContext) -> MethodSetup:
    """Referential game (Algorithm 1), then the translator to the frozen generator's TL (Algorithm 2)."""
    config, cache, data = ctx.config, ctx.cache, ctx.data
    keys = method_stage_keys(config, ctx.upstream_key, cache.key)

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
        window = max(1, losses.shape[1] // 20)
        return {
            "rg_loss_start": losses[:, :window].mean(1).tolist(),
            "rg_loss_end": losses[:, -window:].mean(1).tolist(),
            **timings,
        }

    rg = run_stage(
        config.out, "talar/task_language", keys["talar/task_language"], rg_body, reuse_from=config.reuse_stages
    )

    def targets(stage_dir: Path) -> jax.Array:
        generator_params = load_tree(rg.path / "params.msgpack")["generator"]
        generate = jax.vmap(make_generate_task_language(config.talar), in_axes=(0, None, None))
        return jax.jit(generate)(generator_params, data.states, data.final_states)

    translator = _translator_stage(ctx, "talar/translator", keys["talar/translator"], config.talar.spec, targets)
    return _table_setup(ctx, rg, translator)


def setup_end_to_end(ctx: MethodContext) -> MethodSetup:
    """End-to-end TALAR (Appendix E.6): generator, receiver and translator trained jointly in one stage."""
    config, cache, data = ctx.config, ctx.cache, ctx.translator_data()
    ((stage_name, key),) = method_stage_keys(config, ctx.upstream_key, cache.key).items()

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
        window = max(1, losses.shape[1] // 20)
        return {
            "joint_loss_end": losses[:, -window:].mean(1).tolist(),
            "tl_quality": {k: [q[k] for q in quality] for k in quality[0]},
            **timings,
        }

    return _table_setup(ctx, run_stage(config.out, stage_name, key, body, reuse_from=config.reuse_stages))


def setup_handcrafted(ctx: MethodContext) -> MethodSetup:
    """Appendix E.7: the translator trained to a one-hot of the goal instead of the generator's TL."""
    spec = TaskLanguageSpec(num_predicates=0, num_arguments=1, arg_size=ctx.cache.num_goals)
    goals = goal_one_hot(ctx.dataset.goal_ids, ctx.cache.num_goals)
    key = method_stage_keys(ctx.config, ctx.upstream_key, ctx.cache.key)["handcrafted/translator"]
    stage = _translator_stage(
        ctx, "handcrafted/translator", key, spec, lambda _: np.broadcast_to(goals, (ctx.seeds, *goals.shape))
    )
    return _table_setup(ctx, stage)


def setup_gla(ctx: MethodContext) -> MethodSetup:
    """GLA: a latent-action auto-encoder of (s, s'), then the translator to its binary latent code (|L_T| bits)."""
    config, data = ctx.config, ctx.data
    size, obs = config.talar.spec.size, data.states.shape[-1]
    keys = method_stage_keys(config, ctx.upstream_key, ctx.cache.key)

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

    spec = TaskLanguageSpec(num_predicates=size, num_arguments=0)
    stage = _translator_stage(ctx, "gla/translator", keys["gla/translator"], spec, targets)
    return _table_setup(ctx, gla, stage)


def setup_onehot(ctx: MethodContext) -> MethodSetup:
    """One-hot: a unique one-hot per instruction over train and test instructions together."""
    table = one_hot_table(len(ctx.cache.sentences))
    tables = np.broadcast_to(np.asarray(table, np.float32), (ctx.seeds, *table.shape))
    return _frozen_table_setup(ctx, tables, method_stage_keys(ctx.config, ctx.upstream_key, ctx.cache.key)["onehot"])


def _encoding_setup(ctx: MethodContext, binary: bool, pretrained: bool, aligned: bool = False) -> MethodSetup:
    config = ctx.config
    features = ctx.data.sentence_embeddings  # the experiment's sentence readout (on device already)
    architecture = (config.talar.spec, config.talar.generator_hidden) if aligned else None
    conditioner = EncodingLayerConditioner(features, ctx.lookups(), config.talar.spec.size, binary, architecture)
    name = config.method
    ((stage_name, key),) = method_stage_keys(config, ctx.upstream_key, ctx.cache.key).items()
    if not pretrained:
        return MethodSetup(conditioner, None, key, None)

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


def _finetuned_setup(ctx: MethodContext, binary: bool) -> MethodSetup:
    """Appendix E.5: BERT-binary / -continuous with BERT trained by the policy's loss (``FinetunedBertConditioner``);
    the encoding layer reads the pooled sentence embedding (the paper's BERT readout: a prefix readout would need a
    BERT pass per prefix inside the loop)."""
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
    ((_, key),) = method_stage_keys(config, ctx.upstream_key, cache.key).items()
    return MethodSetup(conditioner, None, key, None)


METHODS: dict[str, Callable[[MethodContext], MethodSetup]] = {
    "talar": setup_talar,
    "onehot": setup_onehot,
    "bert-binary": lambda ctx: _encoding_setup(ctx, binary=True, pretrained=False),
    "bert-continuous": lambda ctx: _encoding_setup(ctx, binary=False, pretrained=False),
    "pretrained-bert-binary": lambda ctx: _encoding_setup(ctx, binary=True, pretrained=True),
    "pretrained-bert-continuous": lambda ctx: _encoding_setup(ctx, binary=False, pretrained=True),
    "gla": setup_gla,
    "handcrafted": setup_handcrafted,
    "aligned-bert-binary": lambda ctx: _encoding_setup(ctx, binary=True, pretrained=False, aligned=True),
    "aligned-bert-continuous": lambda ctx: _encoding_setup(ctx, binary=False, pretrained=False, aligned=True),
    "end-to-end": setup_end_to_end,
    "finetuned-bert-binary": lambda ctx: _finetuned_setup(ctx, binary=True),
    "finetuned-bert-continuous": lambda ctx: _finetuned_setup(ctx, binary=False),
}
PAPER_COMPARISON: tuple[str, ...] = tuple(METHODS)[:8]
"""The eight methods of the paper's Fig. 4 (the Aligned baselines belong to Appendix E.3)."""
METHOD_LABELS: dict[str, str] = {
    "talar": "TALAR",
    "onehot": "One-hot",
    "bert-binary": "BERT-binary",
    "bert-continuous": "BERT-continuous",
    "pretrained-bert-binary": "Pre-trained BERT-binary",
    "pretrained-bert-continuous": "Pre-trained BERT-continuous",
    "gla": "GLA",
    "handcrafted": "Handcrafted",
    "aligned-bert-binary": "Aligned BERT-binary",
    "aligned-bert-continuous": "Aligned BERT-continuous",
    "end-to-end": "End-to-end TALAR",
    "finetuned-bert-binary": "Fine-tuned BERT-binary",
    "finetuned-bert-continuous": "Fine-tuned BERT-continuous",
}
