"""Experiment entry points (``python -m experiments.<name>``).

Importing this package sets up the process before JAX starts (``talar_jax.runtime.configure``: the CPU XLA
flag MJX needs, JAX's persistent compilation cache, line-buffered progress output).
"""

from talar_jax.runtime import configure

configure()
