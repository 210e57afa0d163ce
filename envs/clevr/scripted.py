"""Scripted CLEVR-Robot collector: push the goal's source ball towards the goal's target point.

``greedy_push(state, rng, epsilon)`` is a pure JAX function (jit- and vmap-able) acting in the ``collect`` action
space (``action_type='collect'``: 8 push directions of the goal's source ball). It picks the direction best aligned
with the vector from the source to the dense reward's target point (destination + 0.195 u_relation), and with
probability ``epsilon`` a uniformly random direction, which both diversifies the task dataset and gets the ball
unstuck. Only the source ball is pushed (others move only when hit), as in the original's data collection.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.base import State
from envs.clevr import tasks

_UNIT_DIRECTIONS = tasks.PUSH_DIRECTIONS / (tasks.PUSH_DIRECTIONS**2).sum(-1, keepdims=True) ** 0.5


def greedy_push(state: State, rng: jax.Array, epsilon: float = 0.2) -> jax.Array:
    """() int32 collect action (push direction of the source ball) for one goal-task state."""
    ball_xy = state.obs.reshape(tasks.NUM_BALLS, 2)
    task = state.task
    target = ball_xy[task.destination] + tasks.TARGET_OFFSET * jnp.asarray(tasks.RELATION_VECTORS)[task.relation]
    greedy = jnp.argmax(jnp.asarray(_UNIT_DIRECTIONS) @ (target - ball_xy[task.source]))
    rng_explore, rng_direction = jax.random.split(rng)
    random = jax.random.randint(rng_direction, (), 0, tasks.NUM_DIRECTIONS)
    return jnp.where(jax.random.uniform(rng_explore) < epsilon, random, greedy).astype(jnp.int32)
