"""talar-jax: TALAR and its baselines for natural-language-conditioned RL, in JAX."""

__version__ = "0.1.0"
