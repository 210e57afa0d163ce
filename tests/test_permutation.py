"""``shuffled_order``: the PPO epochs' random minibatch order from one sort of plain 32-bit words."""

import jax
import numpy as np
import pytest

from talar_jax.permutation import shuffled_order


@pytest.mark.parametrize("size", [1, 2, 640, 4096, 70_000])
def test_shuffled_order_is_a_seeded_permutation(size):
    """Every row exactly once, the same for a key, another for another key; above 2^16 rows the argsort path."""
    order = np.asarray(shuffled_order(jax.random.key(0), size))
    np.testing.assert_array_equal(np.sort(order), np.arange(size))
    np.testing.assert_array_equal(order, shuffled_order(jax.random.key(0), size))
    if size > 2:
        assert not np.array_equal(order, shuffled_order(jax.random.key(1), size))


def test_shuffled_order_spreads_every_row_over_every_position():
    """Over many keys each row lands in each minibatch about equally often (no row is tied to its rollout slot)."""
    size, minibatches, draws = 4096, 32, 400
    orders = np.asarray(jax.vmap(lambda k: shuffled_order(k, size))(jax.random.split(jax.random.key(2), draws)))
    minibatch_of_row = np.empty_like(orders)
    np.put_along_axis(minibatch_of_row, orders, np.arange(size)[None] // (size // minibatches), axis=1)
    counts = np.stack([np.bincount(column, minlength=minibatches) for column in minibatch_of_row.T[:64]])
    expected = draws / minibatches
    chi2 = ((counts - expected) ** 2 / expected).sum(1)  # 31 degrees of freedom per row: mean 31, sd ~7.9
    assert 15 < chi2.mean() < 47, chi2.mean()
    first_before_last = (np.argmax(orders == 0, 1) < np.argmax(orders == size - 1, 1)).mean()
    assert 0.4 < first_before_last < 0.6
