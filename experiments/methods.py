"""How each method turns instructions into the policy's conditioning vector (TALAR and the paper's baselines).

Each ``setup_<method>`` runs the method's own cached stages and returns a ``MethodSetup``: the conditioner the
IFP's PPO uses, seed-stacked initial parameters (frozen tables, behaviour-cloned weights), the key of
everything upstream, and per-seed instruction encodings for the t-SNE figure.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from talar_jax.baselines import (
    NLEncodingLayer,
    goal_one_hot,
    make_gla_codes,
    make_train_gla,
    one_hot_table,
)
from talar_jax.conditioning import Conditioner, InstructionSampler, InstructionTableConditioner
from talar_jax.language import EmbeddingCache, load_instructions
from talar_jax.networks import make_ppo_networks
from talar_jax.optim import AdamFit, fit_seeds
from talar_jax.sharding import shard_seeds
from talar_jax.stages import StageResult, run_stage, stable_hash
from talar_jax.talar import (
    TaskLanguageData,
    make_generate_task_language,
    make_train_task_language,
    make_train_translator,
    make_translate,
    task_language_quality,
)
from talar_jax.task_language import TaskLanguageSpec


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


@dataclasses.dataclass(frozen=True)
class MethodContext:
    """Inputs shared by every method of one experiment."""

    config: Any  # ExperimentConfig
    upstream_key: str  # key of the oracle/dataset stage
    data: TaskLanguageData
    cache: EmbeddingCache
    dataset: Any  # TaskDataset
    env: Any

    @property
    def seeds(self) -> int:
        return self.config.seeds

    def named(self, *stages: StageResult) -> dict[str, StageResult]:
        """Stages by their folder relative to ``out`` (the keys of ``stage_seconds``)."""
        return {stage.path.relative_to(self.config.out).as_posix(): stage for stage in stages}

    def seed_keys(self, stage: str) -> jax.Array:
        """(seeds,) keys of a stage, stable across processes (crc32 of the name, not Python's hash)."""
        key = jax.random.fold_in(jax.random.PRNGKey(self.config.seed), zlib.crc32(stage.encode()))
        return shard_seeds(jax.random.split(key, self.seeds), self.seeds)

    def lookups(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """split -> (goal -> cache rows of its instructions, counts); CLEVR training may keep only k patterns."""
        lookups = {}
        for split in ("train", "test"):
            patterns = self.config.num_patterns if split == "train" else None
            instructions = load_instructions(self.config.env, split, num_patterns=patterns)
            lookups[split] = (instructions.goal_cache_rows(), instructions.goal_sentence_counts)
        return lookups


def save_tree(path: Path, tree: Any) -> None:
    """Writes a pytree of arrays with msgpack (atomic rename)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(serialization.msgpack_serialize(jax.device_get(tree)))
    tmp.replace(path)


def load_tree(path: Path) -> Any:
    return serialization.msgpack_restore(path.read_bytes())


class FrozenTableConditioner(InstructionTableConditioner):
    """A per-seed instruction table that PPO carries in ``params["conditioner"]`` but never changes."""

    trainable = False

    def init(self, rng: jax.Array) -> Any:
        del rng
        return {"table": self.table}

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        table = jax.lax.stop_gradient(params["table"])
        return jnp.where(instruction >= 0, table[jnp.maximum(instruction, 0)], 0.0)


class EncodingLayerConditioner(Conditioner):
    """BERT-binary / BERT-continuous: a trainable dense layer on the frozen sentence features."""

    def __init__(self, sentence_embeddings: np.ndarray | jax.Array, lookups: dict, size: int, binary: bool):
        self.embeddings = jnp.asarray(sentence_embeddings, jnp.float32)
        self.layer = NLEncodingLayer(size, binary)
        self.size = size
        self.sampler = InstructionSampler(lookups, num_instructions=len(sentence_embeddings))

    def init(self, rng: jax.Array) -> Any:
        return self.layer.init(rng, self.embeddings[:1])

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        return self.sampler.sample(rng, goal, split)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        out = self.layer.apply(params, self.embeddings[jnp.maximum(instruction, 0)], None)
        return jnp.where(instruction >= 0, out, 0.0)


def _table_setup(ctx: MethodContext, *stages: StageResult) -> MethodSetup:
    """A frozen per-seed table from the last stage's ``tables.npy``; all ``stages`` reported."""
    tables = np.asarray(np.load(stages[-1].path / "tables.npy"), np.float32)
    return _frozen_table_setup(ctx, tables, stages[-1].key, stages)


def _frozen_table_setup(ctx: MethodContext, tables: np.ndarray, key: str, stages=()) -> MethodSetup:
    conditioner = FrozenTableConditioner(tables[0], ctx.lookups())
    return MethodSetup(conditioner, {"conditioner": {"table": tables}}, key, tables, ctx.named(*stages))


def _translator_stage(ctx: MethodContext, name: str, key: str, spec: TaskLanguageSpec, targets_fn) -> StageResult:
    """Trains one translator per seed to ``targets_fn(stage_dir) -> (seeds, N, |L|)``; saves translated tables."""
    config, cache, data = ctx.config, ctx.cache, ctx.data

    def body(stage_dir: Path) -> dict[str, Any]:
        targets = jnp.asarray(targets_fn(stage_dir), jnp.float32)
        fit = make_train_translator(config.talar, spec)
        params, losses = fit_seeds(fit, ctx.seed_keys(name), targets, data, in_axes=(0, None), label=name,
                                   progress=config.progress)  # fmt: skip
        tables = np.asarray(jax.jit(jax.vmap(make_translate(config.talar, spec), in_axes=(0, None)))(
            params, data.sentence_embeddings))  # fmt: skip
        save_tree(stage_dir / "params.msgpack", params)
        np.save(stage_dir / "tables.npy", tables)
        quality = [task_language_quality(t, cache.goal_ids, cache.is_train) for t in tables]
        return {
            "translator_loss_end": losses[:, -max(1, losses.shape[1] // 20) :].mean(1).tolist(),
            "tl_quality": {k: [q[k] for q in quality] for k in quality[0]},
            "distinct_target_codes": [len(np.unique(np.asarray(t).round(), axis=0)) for t in targets],
        }

    return run_stage(config.out, name, key, body)


def setup_talar(ctx: MethodContext) -> MethodSetup:
    """Referential game (Algorithm 1), then the translator to the frozen generator's TL (Algorithm 2)."""
    config, cache, data = ctx.config, ctx.cache, ctx.data
    rg_key = stable_hash("task_language", ctx.upstream_key, cache.key, config.talar, config.seeds, config.seed)

    def rg_body(stage_dir: Path) -> dict[str, Any]:
        fit = make_train_task_language(config.talar, cache.vocab_size, cache.max_tokens)
        params, losses = fit_seeds(fit, ctx.seed_keys("task_language"), data, label="talar/referential game",
                                   progress=config.progress)  # fmt: skip
        save_tree(stage_dir / "params.msgpack", params)
        np.save(stage_dir / "losses.npy", losses)
        window = max(1, losses.shape[1] // 20)
        return {"rg_loss_start": losses[:, :window].mean(1).tolist(),
                "rg_loss_end": losses[:, -window:].mean(1).tolist()}  # fmt: skip

    rg = run_stage(config.out, "talar/task_language", rg_key, rg_body)

    def targets(stage_dir: Path) -> jax.Array:
        generator_params = load_tree(rg.path / "params.msgpack")["generator"]
        generate = jax.vmap(make_generate_task_language(config.talar), in_axes=(0, None, None))
        return jax.jit(generate)(generator_params, data.states, data.final_states)

    key = stable_hash("translator", rg.key, config.sentence_readout)
    translator = _translator_stage(ctx, "talar/translator", key, config.talar.spec, targets)
    return _table_setup(ctx, rg, translator)


def setup_handcrafted(ctx: MethodContext) -> MethodSetup:
    """Appendix E.7: the translator trained to a one-hot of the goal instead of the generator's TL."""
    spec = TaskLanguageSpec(num_predicates=0, num_arguments=1, arg_size=ctx.cache.num_goals)
    goals = goal_one_hot(ctx.dataset.goal_ids, ctx.cache.num_goals)
    key = stable_hash("handcrafted", ctx.upstream_key, ctx.cache.key, ctx.config.talar, ctx.seeds, ctx.config.seed,
                      ctx.config.sentence_readout)  # fmt: skip
    stage = _translator_stage(ctx, "handcrafted/translator", key, spec, lambda _: np.broadcast_to(
        goals, (ctx.seeds, *goals.shape)))  # fmt: skip
    return _table_setup(ctx, stage)


def setup_gla(ctx: MethodContext) -> MethodSetup:
    """GLA: a latent-action auto-encoder of (s, s'), then the translator to its binary latent code (|L_T| bits)."""
    config, data = ctx.config, ctx.data
    size, obs = config.talar.spec.size, data.states.shape[-1]
    gla_key = stable_hash("gla", ctx.upstream_key, config.talar, ctx.seeds, config.seed)

    def gla_body(stage_dir: Path) -> dict[str, Any]:
        fit = make_train_gla(size, obs, config.talar.rg_steps, config.talar.batch_size, config.talar.rg_learning_rate)
        params, losses = fit_seeds(fit, ctx.seed_keys("gla"), data.states, data.final_states, label="gla/autoencoder",
                                   progress=config.progress)  # fmt: skip
        save_tree(stage_dir / "params.msgpack", params)
        return {"reconstruction_mse_end": losses[:, -100:].mean(1).tolist()}

    gla = run_stage(config.out, "gla/autoencoder", gla_key, gla_body)

    def targets(stage_dir: Path) -> jax.Array:
        codes = jax.vmap(make_gla_codes(size, obs), in_axes=(0, None, None))
        return jax.jit(codes)(load_tree(gla.path / "params.msgpack"), data.states, data.final_states)

    spec = TaskLanguageSpec(num_predicates=size, num_arguments=0)
    key = stable_hash("gla_translator", gla.key, config.sentence_readout)
    stage = _translator_stage(ctx, "gla/translator", key, spec, targets)
    return _table_setup(ctx, gla, stage)


def setup_onehot(ctx: MethodContext) -> MethodSetup:
    """One-hot: a unique one-hot per instruction over train and test instructions together."""
    table = one_hot_table(len(ctx.cache.sentences))
    tables = np.broadcast_to(np.asarray(table, np.float32), (ctx.seeds, *table.shape))
    return _frozen_table_setup(ctx, tables, stable_hash("onehot", ctx.cache.key))


def _encoding_setup(ctx: MethodContext, binary: bool, pretrained: bool) -> MethodSetup:
    config = ctx.config
    features = ctx.data.sentence_embeddings  # the same sentence readout the translators get (on device already)
    conditioner = EncodingLayerConditioner(features, ctx.lookups(), config.talar.spec.size, binary)
    name = f"{'pretrained-' if pretrained else ''}bert-{'binary' if binary else 'continuous'}"
    if not pretrained:
        return MethodSetup(conditioner, None, stable_hash(name, ctx.cache.key, config.sentence_readout), None)
    key = stable_hash(name, ctx.upstream_key, ctx.cache.key, config.ifp.hidden_sizes, config.talar, ctx.seeds,
                      config.sentence_readout)  # fmt: skip

    def bc_body(stage_dir: Path) -> dict[str, Any]:
        fit = make_behaviour_cloning(ctx, conditioner, steps=config.talar.translator_steps)
        params, losses = fit_seeds(fit, ctx.seed_keys(name), label=f"{name}/behaviour cloning",
                                   progress=config.progress)  # fmt: skip
        save_tree(stage_dir / "params.msgpack", params)
        return {"bc_nll_end": losses[:, -100:].mean(1).tolist()}

    stage = run_stage(config.out, f"{name}/behaviour_cloning", key, bc_body)
    params = load_tree(stage.path / "params.msgpack")
    return MethodSetup(conditioner, params, stage.key, None, ctx.named(stage))


def make_behaviour_cloning(ctx: MethodContext, conditioner: Conditioner, steps: int) -> AdamFit:
    """``fit(rng) -> ({"policy", "conditioner"}, losses)``: maximise log pi(a_i | s_i, enc(L_N)) on the dataset."""
    config, dataset = ctx.config, ctx.dataset
    env = ctx.env
    networks = make_ppo_networks(env.observation_size, conditioner.size, env.action_spec, config.ifp.hidden_sizes)
    states = jnp.asarray(dataset.states, jnp.float32)
    actions = jnp.asarray(dataset.actions)
    instructions = jnp.asarray(dataset.instruction_ids, jnp.int32)

    def loss_fn(params, rng_step):
        rows = jax.random.randint(rng_step, (config.talar.batch_size,), 0, states.shape[0])
        cond = jax.vmap(conditioner.apply, in_axes=(None, 0))(params["conditioner"], instructions[rows])
        dist = networks.policy.apply(params["policy"], jnp.concatenate([states[rows], cond], -1))
        return -networks.distribution.log_prob(dist, actions[rows]).mean()

    def init_params(rng):
        rng_policy, rng_conditioner = jax.random.split(rng)
        return {"policy": networks.init(rng_policy)["policy"], "conditioner": conditioner.init(rng_conditioner)}

    return AdamFit(init_params, loss_fn, config.talar.translator_learning_rate, steps)


METHODS: dict[str, Callable[[MethodContext], MethodSetup]] = {
    "talar": setup_talar,
    "onehot": setup_onehot,
    "bert-binary": lambda ctx: _encoding_setup(ctx, binary=True, pretrained=False),
    "bert-continuous": lambda ctx: _encoding_setup(ctx, binary=False, pretrained=False),
    "pretrained-bert-binary": lambda ctx: _encoding_setup(ctx, binary=True, pretrained=True),
    "pretrained-bert-continuous": lambda ctx: _encoding_setup(ctx, binary=False, pretrained=True),
    "gla": setup_gla,
    "handcrafted": setup_handcrafted,
}
METHOD_LABELS: dict[str, str] = {
    "talar": "TALAR", "onehot": "One-hot", "bert-binary": "BERT-binary", "bert-continuous": "BERT-continuous",
    "pretrained-bert-binary": "Pre-trained BERT-binary", "pretrained-bert-continuous": "Pre-trained BERT-continuous",
    "gla": "GLA", "handcrafted": "Handcrafted",
}  # fmt: skip
