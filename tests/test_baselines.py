"""Baseline encodings: straight-through binary codes, the NL encoding layer, GLA's latent-action auto-encoder."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from talar_jax.baselines import (
    AlignedEncodingLayer,
    EncodingLayerConditioner,
    FinetunedBertConditioner,
    NLEncodingLayer,
    goal_one_hot,
    make_gla_codes,
    make_train_gla,
    one_hot_table,
    straight_through_bernoulli,
)
from talar_jax.language import BertModel, load_encoder
from talar_jax.ppo import PPOConfig, make_train, run_ppo
from talar_jax.task_language import TaskLanguageGenerator, TaskLanguageSpec
from tests.conftest import TINY_BERT
from tests.point_env import PointConfig, PointEnv


def test_straight_through_bernoulli_values_and_gradient():
    logits = jnp.array([-3.0, 0.0, 3.0])
    np.testing.assert_array_equal(straight_through_bernoulli(logits, None), [0.0, 0.0, 1.0])
    samples = jax.vmap(lambda k: straight_through_bernoulli(logits, k))(jax.random.split(jax.random.key(0), 4000))
    np.testing.assert_allclose(samples.mean(0), jax.nn.sigmoid(logits), atol=0.03)
    grad = jax.grad(lambda x: straight_through_bernoulli(x, None).sum())(logits)
    np.testing.assert_allclose(grad, jax.nn.sigmoid(logits) * (1 - jax.nn.sigmoid(logits)), rtol=1e-6)


def test_encoding_layer_and_tables():
    for binary in (True, False):
        layer = NLEncodingLayer(size=14, binary=binary)
        x = jnp.ones((3, 8))
        out = layer.apply(layer.init(jax.random.key(0), x), x, jax.random.key(1))
        assert out.shape == (3, 14)
        if binary:
            assert set(np.unique(np.asarray(out)).tolist()) <= {0.0, 1.0}
        else:
            assert np.all(np.abs(np.asarray(out)) < 1)
    np.testing.assert_array_equal(one_hot_table(3), np.eye(3))
    np.testing.assert_array_equal(goal_one_hot(np.array([2, 0]), 3), [[0, 0, 1], [1, 0, 0]])


def test_aligned_encoding_is_the_task_language_generator_on_the_sentence():
    """Appendix E.3's Aligned baselines: with the same weights, the binary layer computes what the TL generator
    computes for a 'state pair' that is the sentence embedding; the continuous one its softmax probabilities."""
    spec = TaskLanguageSpec(num_predicates=3, num_arguments=2, arg_size=4)
    x = jax.random.normal(jax.random.key(0), (5, 8))
    binary = AlignedEncodingLayer(spec, (16, 16), binary=True)
    params = binary.init(jax.random.key(1), x)
    generator = TaskLanguageGenerator(spec, (16, 16))
    np.testing.assert_array_equal(binary.apply(params, x), generator.apply(params, x, x[:, :0], None))
    code = np.asarray(binary.apply(params, x))
    assert code.shape == (5, spec.size) and set(np.unique(code).tolist()) <= {0.0, 1.0}
    np.testing.assert_array_equal(code[:, spec.num_predicates :].reshape(5, 2, 4).sum(-1), 1.0)  # one-hot arguments
    soft = np.asarray(AlignedEncodingLayer(spec, (16, 16), binary=False).apply(params, x))
    assert np.all((soft > 0) & (soft < 1))
    np.testing.assert_allclose(soft[:, spec.num_predicates :].reshape(5, 2, 4).sum(-1), 1.0, rtol=1e-5)
    grads = jax.grad(lambda p: binary.apply(p, x).sum())(params)  # straight-through: every network gets a gradient
    assert all(float(jnp.abs(g).sum()) > 0 for g in jax.tree.leaves(grads))

    conditioner = EncodingLayerConditioner(
        x, {"train": (np.zeros((2, 1)), np.ones(2))}, spec.size, True, aligned=(spec, (16, 16))
    )
    assert isinstance(conditioner.layer, AlignedEncodingLayer) and conditioner.encodes_table
    with pytest.raises(ValueError, match="differs"):
        EncodingLayerConditioner(
            x, {"train": (np.zeros((2, 1)), np.ones(2))}, spec.size + 1, True, aligned=(spec, (16, 16))
        )


@pytest.mark.parametrize("binary", [True, False])
def test_aligned_conditioner_gathers_rows_of_the_table_encoding_with_the_per_row_values_and_gradient(binary):
    """The aligned conditioner gathers rows of a table encoding (every instruction per rollout, the training ones
    per loss minibatch): the same vectors, zeros for -1 and the same gradient as encoding each row."""
    spec = TaskLanguageSpec(num_predicates=2, num_arguments=2, arg_size=3)
    features = jax.random.normal(jax.random.key(0), (8, 10))
    lookups = {"train": (np.array([[0, 3], [6, -1]]), np.array([2, 1])), "test": (np.array([[1], [7]]), np.ones(2))}
    conditioner = EncodingLayerConditioner(features, lookups, spec.size, binary, aligned=(spec, (16,)))
    np.testing.assert_array_equal(conditioner.loss_rows, [0, 3, 6])
    params = conditioner.init(jax.random.key(1))
    instructions = jnp.array([3, -1, 0, 3, 6])  # training instructions, as the loss reads

    def per_row(p):
        out = conditioner.layer.apply(p, features[jnp.maximum(instructions, 0)], None)
        return jnp.where((instructions >= 0)[:, None], out, 0.0)

    reference = per_row(params)
    assert np.abs(np.asarray(reference)).sum() > 0 and np.all(np.asarray(reference)[1] == 0)
    np.testing.assert_allclose(conditioner.apply_batch(params, instructions), reference, atol=1e-6)
    frozen = conditioner.freeze(params)
    assert set(frozen) == {"codes"} and frozen["codes"].shape == (8, spec.size)
    np.testing.assert_allclose(conditioner.apply_batch(frozen, instructions), reference, atol=1e-6)
    np.testing.assert_allclose(conditioner.apply(frozen, jnp.int32(6)), reference[4], atol=1e-6)
    np.testing.assert_allclose(conditioner.apply(params, jnp.int32(-1)), np.zeros(spec.size))
    test_code = conditioner.layer.apply(params, features[7], None)  # acting on a test instruction: its own code
    np.testing.assert_allclose(conditioner.apply(frozen, jnp.int32(7)), test_code, atol=1e-6)
    np.testing.assert_allclose(conditioner.apply(params, jnp.int32(7)), test_code, atol=1e-6)
    weights = jax.random.normal(jax.random.key(2), reference.shape)
    grad = jax.grad(lambda p: jnp.sum(conditioner.apply_batch(p, instructions) * weights))(params)
    expected = jax.grad(lambda p: jnp.sum(per_row(p) * weights))(params)
    for g, e in zip(jax.tree.leaves(grad), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(g, e, rtol=1e-5, atol=1e-6)
    assert sum(float(jnp.abs(g).sum()) for g in jax.tree.leaves(grad)) > 0


def test_gla_autoencoder_learns_to_reconstruct_goal_dependent_changes():
    rng = np.random.default_rng(0)
    offsets = rng.normal(size=(4, 5)) * 2
    goals = rng.integers(0, 4, 2048)
    states = rng.normal(size=(2048, 5)).astype(np.float32)
    final_states = (states + offsets[goals]).astype(np.float32)
    train = jax.jit(make_train_gla(latent_size=6, observation_size=5, steps=1500, batch_size=128, learning_rate=3e-3))
    params, losses = train(jax.random.key(0), jnp.asarray(states), jnp.asarray(final_states))
    baseline = float(np.mean((final_states - final_states.mean(0)) ** 2))
    assert float(losses[-100:].mean()) < 0.2 * baseline, (float(losses[-100:].mean()), baseline)
    codes = np.asarray(make_gla_codes(6, 5)(params, jnp.asarray(states), jnp.asarray(final_states)))
    # The latent code identifies the goal: at most one goal per code among frequent codes.
    purity = np.mean([np.bincount(goals[(codes == c).all(1)]).max() / (codes == c).all(1).sum() for c in codes[:200]])
    assert purity > 0.9, purity


# ------------------------------------------------------------------------------------ fine-tuned BERT (Fig. 14)


def _token_sentences(encoder, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``count`` distinct random word-piece sequences of the tiny encoder's vocabulary with [CLS]/[SEP], padded."""
    rng = np.random.default_rng(seed)
    ordinary = [
        i for i in range(encoder.config.vocab_size) if i not in (encoder.pad_id, encoder.cls_id, encoder.sep_id)
    ]
    sequences = [encoder.with_specials(rng.choice(ordinary, rng.integers(3, 9)).tolist()) for _ in range(count)]
    return encoder.pad(sequences)


def test_bert_layer_slices_compose_to_the_whole_model():
    encoder = load_encoder(TINY_BERT)
    ids, mask = _token_sentences(encoder, 5)
    whole = encoder.hidden_states(ids, mask)
    layers = encoder.config.num_hidden_layers
    below = BertModel(encoder.config, layers=(0, 1)).apply(encoder.params, ids, mask)
    above = BertModel(encoder.config, layers=(1, layers)).apply(encoder.params, below, mask)
    np.testing.assert_allclose(np.asarray(above) * mask[..., None], whole * mask[..., None], atol=1e-5)
    with pytest.raises(ValueError, match="0 <= first <= stop"):
        BertModel(encoder.config, layers=(1, layers + 1)).apply(encoder.params, below, mask)


@pytest.mark.parametrize("first_layer", [0, 1])
def test_finetuned_bert_starts_at_the_frozen_encoding_and_its_loss_trains_bert(first_layer):
    encoder = load_encoder(TINY_BERT)
    ids, mask = _token_sentences(encoder, 8)
    lookup = {"train": (np.arange(8).reshape(4, 2), np.full(4, 2))}
    train_rows = np.array([0, 1, 2, 3, 4, 5])  # rows 6, 7 only ever read frozen
    conditioner = FinetunedBertConditioner(
        encoder.config, encoder.params, ids, mask, lookup, 6, False, first_layer, train_rows
    )
    params = conditioner.init(jax.random.PRNGKey(0))
    trained = set(params["bert"])
    assert trained == ({"embeddings", "layer_0", "layer_1"} if first_layer == 0 else {"layer_1"})
    # at the start, the codes are the frozen BERT-continuous layer's on the encoder's pooled sentence embedding
    pooled = encoder.embed_sequences([row[m > 0].tolist() for row, m in zip(ids, mask, strict=True)])
    frozen = EncodingLayerConditioner(pooled, lookup, 6, binary=False)
    instructions = jnp.array([0, 3, 7, -1, 5])
    reference = frozen.apply_batch(params["layer"], instructions)
    np.testing.assert_allclose(conditioner.apply_batch(conditioner.freeze(params), instructions), reference, atol=1e-5)
    np.testing.assert_allclose(conditioner.apply(conditioner.freeze(params), jnp.int32(3)), reference[1], atol=1e-5)
    loss_rows = jnp.array([0, 3, 5, -1])  # the loss encodes the training rows in one pass
    np.testing.assert_allclose(
        conditioner.apply_batch(params, loss_rows), frozen.apply_batch(params["layer"], loss_rows), atol=1e-5
    )
    grads = jax.grad(lambda p: jnp.sum(conditioner.apply_batch(p, loss_rows) ** 2))(params)
    assert all(float(optax.global_norm(grads["bert"][name])) > 0 for name in trained)
    frozen_grad = jax.grad(lambda p: jnp.sum(conditioner.apply_batch(conditioner.freeze(p), loss_rows) ** 2))(params)
    assert float(optax.global_norm(frozen_grad["bert"])) == 0.0


def test_one_ppo_update_moves_the_finetuned_bert():
    encoder = load_encoder(TINY_BERT)
    ids, mask = _token_sentences(encoder, 8, seed=1)
    lookup = {"train": (np.arange(8, dtype=np.int32).reshape(4, 2), np.full(4, 2, np.int32))}
    conditioner = FinetunedBertConditioner(encoder.config, encoder.params, ids, mask, lookup, 8, True, 1, np.arange(8))
    config = PPOConfig(num_envs=8, rollout_length=16, minibatch_size=64, num_epochs=2, updates_per_chunk=1)
    learner = make_train(config, PointEnv(), conditioner)
    state = learner.init(jax.random.PRNGKey(0))
    after, _ = jax.jit(learner.chunk)(state)
    moved = jax.tree.map(
        lambda a, b: float(jnp.max(jnp.abs(a - b))), after.params["conditioner"], state.params["conditioner"]
    )
    assert min(jax.tree.leaves(moved["bert"])) > 0 and max(jax.tree.leaves(moved["layer"])) > 0
    assert set(after.opt_state[1][0].mu["conditioner"]["bert"]) == {"layer_1"}  # Adam state for the trained layer only


def test_ppo_trains_the_finetuned_bert_with_the_policy():
    encoder = load_encoder(TINY_BERT)
    ids, mask = _token_sentences(encoder, 8, seed=1)
    lookup = {"train": (np.arange(8, dtype=np.int32).reshape(4, 2), np.full(4, 2, np.int32))}
    conditioner = FinetunedBertConditioner(encoder.config, encoder.params, ids, mask, lookup, 8, False, 0, np.arange(8))
    config = PPOConfig(
        num_envs=16, rollout_length=32, total_env_steps=20_480, updates_per_chunk=10, num_seeds=1, eval_episodes=64
    )
    result = run_ppo(
        config, PointEnv(PointConfig(continuous=True)), conditioner, None, progress=False, eval_splits=("train",)
    )
    assert result.last_eval["train"]["success"] >= 0.8, result.last_eval["train"]
    start = conditioner.init(jax.random.PRNGKey(0))["bert"]
    moved = jax.tree.map(lambda a, b: float(jnp.max(jnp.abs(a[0] - b))), result.params["conditioner"]["bert"], start)
    assert max(jax.tree.leaves(moved)) > 1e-4  # BERT itself was optimised with the policy


def test_finetuned_bert_from_a_cache_masks_each_sentences_padding():
    encoder = load_encoder(TINY_BERT)
    ids, mask = _token_sentences(encoder, 6, seed=2)
    cache = SimpleNamespace(token_ids=ids, token_lengths=mask.sum(1))
    lookup = {"train": (np.arange(6).reshape(3, 2), np.full(3, 2))}
    built = FinetunedBertConditioner.from_cache(encoder, cache, lookup, 5, True, 1, np.arange(4))
    direct = FinetunedBertConditioner(encoder.config, encoder.params, ids, mask, lookup, 5, True, 1, np.arange(4))
    np.testing.assert_array_equal(built.mask, mask)
    params = direct.init(jax.random.PRNGKey(3))
    np.testing.assert_allclose(built.freeze(params)["codes"], direct.freeze(params)["codes"], atol=1e-6)
