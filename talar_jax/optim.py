"""One supervised training loop for the small networks (generator, translator, GLA, behaviour cloning)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import optax


def fit_with_adam(
    loss_fn: Callable[[Any, jax.Array], jax.Array], params: Any, learning_rate: float, rng: jax.Array, steps: int
) -> tuple[Any, jax.Array]:
    """Minimises ``loss_fn(params, rng_step)`` with Adam for ``steps`` steps inside one ``lax.scan``.

    Returns:
        (final params, (steps,) loss per step).
    """
    optimizer = optax.adam(learning_rate)

    def update(carry, rng_step):
        params, opt_state = carry
        loss, grads = jax.value_and_grad(loss_fn)(params, rng_step)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), loss

    (params, _), losses = jax.lax.scan(update, (params, optimizer.init(params)), jax.random.split(rng, steps))
    return params, losses
