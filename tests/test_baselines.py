"""Baseline encodings: straight-through binary codes, the NL encoding layer, GLA's latent-action auto-encoder."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from talar_jax.baselines import (
    AlignedEncodingLayer,
    EncodingLayerConditioner,
    NLEncodingLayer,
    goal_one_hot,
    make_gla_codes,
    make_train_gla,
    one_hot_table,
    straight_through_bernoulli,
)
from talar_jax.task_language import TaskLanguageGenerator, TaskLanguageSpec


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
    assert isinstance(conditioner.layer, AlignedEncodingLayer)
    with pytest.raises(ValueError, match="differs"):
        EncodingLayerConditioner(
            x, {"train": (np.zeros((2, 1)), np.ones(2))}, spec.size + 1, True, aligned=(spec, (16, 16))
        )


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
