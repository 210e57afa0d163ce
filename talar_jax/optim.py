"""One supervised training loop for the small networks (generator, translator, GLA, behaviour cloning).

An ``AdamFit`` is a pure description of a fit (how to initialise the parameters, the loss, the LR and the number
of steps). Calling it runs the whole fit in one ``lax.scan``; ``fit_seeds`` runs it vmapped over seeds in jitted
chunks with a progress line between chunks (host work stays outside the compiled code). Step ``i`` draws its
randomness from ``fold_in(key, i)``, so the result does not depend on how the steps are chunked.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import serialization

from envs.runtime import program_compiler_options
from talar_jax.checkpoint import load_tree, save_tree


class FitState(NamedTuple):
    """Parameters, Adam state, the key of the step stream and the number of steps taken."""

    params: Any
    opt_state: Any
    rng: jax.Array
    step: jax.Array


@dataclasses.dataclass(frozen=True)
class AdamFit:
    """Minimises ``loss(params, rng_step, *inputs)`` with Adam.

    Attributes:
        init_params: ``(rng, *inputs) -> params``.
        loss: ``(params, rng_step, *inputs) -> scalar``.
        learning_rate: Adam's learning rate.
        steps: gradient steps of the whole fit.
    """

    init_params: Callable[..., Any]
    loss: Callable[..., jax.Array]
    learning_rate: float
    steps: int

    @property
    def optimizer(self) -> optax.GradientTransformation:
        return optax.adam(self.learning_rate)

    def init(self, rng: jax.Array, *inputs: Any) -> FitState:
        rng_init, rng_steps = jax.random.split(rng)
        params = self.init_params(rng_init, *inputs)
        return FitState(params, self.optimizer.init(params), rng_steps, jnp.zeros((), jnp.int32))

    def run(self, state: FitState, *inputs: Any, steps: int) -> tuple[FitState, jax.Array]:
        """``steps`` more gradient steps (one ``lax.scan``); returns the new state and (steps,) losses."""

        def update(carry, index):
            params, opt_state = carry
            loss, grads = jax.value_and_grad(self.loss)(params, jax.random.fold_in(state.rng, index), *inputs)
            updates, opt_state = self.optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), loss

        (params, opt_state), losses = jax.lax.scan(
            update, (state.params, state.opt_state), state.step + jnp.arange(steps, dtype=jnp.int32)
        )
        return FitState(params, opt_state, state.rng, state.step + steps), losses

    def __call__(self, rng: jax.Array, *inputs: Any) -> tuple[Any, jax.Array]:
        """The whole fit: (final params, (steps,) loss per step)."""
        state, losses = self.run(self.init(rng, *inputs), *inputs, steps=self.steps)
        return state.params, losses


class _PieceRunners:
    """``fit``'s pieces vmapped over seeds: one compiled program per piece length, and the seconds compiling took."""

    def __init__(self, fit: AdamFit, in_axes: tuple[int | None, ...]):
        self.fit = fit
        self.in_axes = in_axes
        self.compiled: dict[int, Callable] = {}
        self.compile_s = 0.0

    def __call__(self, steps: int, state: FitState, inputs: tuple[Any, ...]) -> tuple[FitState, jax.Array]:
        """``steps`` more steps of every seed (compiled on first use of that length): new state, (seeds, steps)
        losses."""
        if steps not in self.compiled:
            compile_start = time.perf_counter()
            fit = self.fit
            runner = jax.jit(jax.vmap(lambda s, *x, n=steps: fit.run(s, *x, steps=n), in_axes=(0, *self.in_axes)))
            options = program_compiler_options(steps_mjx=False)  # supervised fits step no physics
            self.compiled[steps] = runner.lower(state, *inputs).compile(compiler_options=options)
            self.compile_s += time.perf_counter() - compile_start
        return self.compiled[steps](state, *inputs)


def _resume_fit(
    checkpoint: str | Path | None,
    state: FitState,
    restart: Callable[[], FitState],
    steps: int,
    label: str,
    progress: bool,
) -> tuple[FitState, list[np.ndarray], int]:
    """(state, losses so far, steps done) of a fit of ``steps`` steps: ``checkpoint``'s when it holds one of at most
    that many steps; a fresh start (``state``, or ``restart()`` after reading a longer fit's) otherwise."""
    if checkpoint is None or not Path(checkpoint).is_file():
        return state, [], 0
    state, restored = _restore_fit(Path(checkpoint), state)
    if restored.shape[1] > steps:  # a longer fit's state: start again
        return restart(), [], 0
    if progress:
        print(f"{label}: resumed at step {restored.shape[1]}/{steps} from {checkpoint}", flush=True)
    return state, [restored], restored.shape[1]


def fit_seeds(
    fit: AdamFit,
    seed_keys: jax.Array,
    *inputs: Any,
    in_axes: tuple[int | None, ...] | None = None,
    label: str = "fit",
    chunks: int = 10,
    progress: bool = True,
    timings: dict[str, float] | None = None,
    checkpoint: str | Path | None = None,
) -> tuple[Any, np.ndarray]:
    """Runs ``fit`` for every seed (vmapped) in up to ``chunks`` jitted pieces, printing progress between them.

    Args:
        fit: the fit.
        seed_keys: (seeds,) keys.
        *inputs: the loss's inputs.
        in_axes: vmap axis of each input (None: shared by all seeds, the default for every input).
        label: name in the progress line.
        chunks: number of pieces (at most two distinct chunk lengths are compiled).
        progress: print a line after each piece.
        timings: if given, filled with ``compile_s`` (compiling the pieces) and ``run_s`` (running them).
        checkpoint: a file the fit's state and losses are saved to after every piece and resumed from when it
            exists (a stage's ``checkpoints/`` folder, kept while the stage's key is unchanged). Step ``i`` draws
            ``fold_in(key, i)``, so a resumed fit ends where an uninterrupted one does.

    Returns:
        (seed-stacked final params, (seeds, steps) losses as numpy).
    """
    in_axes = tuple(in_axes) if in_axes is not None else (None,) * len(inputs)
    if len(in_axes) != len(inputs):
        raise ValueError(f"fit_seeds: {len(inputs)} inputs but {len(in_axes)} in_axes")
    init = jax.jit(jax.vmap(fit.init, in_axes=(0, *in_axes)))
    runners = _PieceRunners(fit, in_axes)
    state = init(seed_keys, *inputs)
    chunk = -(-fit.steps // max(1, min(chunks, fit.steps)))
    start = time.perf_counter()
    state, losses, done = _resume_fit(checkpoint, state, lambda: init(seed_keys, *inputs), fit.steps, label, progress)
    while done < fit.steps:
        steps = min(chunk, fit.steps - done)
        state, chunk_losses = runners(steps, state, inputs)
        losses.append(np.asarray(chunk_losses))
        done += steps
        if checkpoint is not None:
            _save_fit(Path(checkpoint), state, np.concatenate(losses, axis=1))
        if progress:
            recent = losses[-1][:, -max(1, steps // 10) :].mean()
            print(
                f"{label}: step {done}/{fit.steps}, loss {recent:.4f} (mean over seeds), "
                f"{time.perf_counter() - start:.0f} s",
                flush=True,
            )
    if timings is not None:
        timings.update(compile_s=runners.compile_s, run_s=time.perf_counter() - start - runners.compile_s)
    return state.params, np.concatenate(losses, axis=1)


def _is_key(x: Any) -> bool:
    return jnp.issubdtype(jnp.asarray(x).dtype, jax.dtypes.prng_key)


def _raw_keys(tree: Any) -> Any:
    """``tree`` with typed PRNG keys replaced by their raw data (what msgpack can store)."""
    return jax.tree.map(lambda x: jax.random.key_data(x) if _is_key(x) else x, tree)


def _save_fit(path: Path, state: FitState, losses: np.ndarray) -> None:
    """``state`` (typed PRNG keys as their raw data) and the (seeds, steps so far) losses, written atomically."""
    raw = _raw_keys(state)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_tree(path, {"state": serialization.to_state_dict(raw), "losses": losses})


def _restore_fit(path: Path, template: FitState) -> tuple[FitState, np.ndarray]:
    """The state saved by ``_save_fit``, placed like ``template``'s leaves, and its losses."""
    stored = load_tree(path)
    raw = serialization.from_state_dict(_raw_keys(template), stored["state"])

    def place(like, value):
        value = jax.random.wrap_key_data(value, impl=jax.random.key_impl(like)) if _is_key(like) else value
        return jax.device_put(jnp.asarray(value, like.dtype), like.sharding)

    return jax.tree.map(place, template, raw), np.asarray(stored["losses"])
