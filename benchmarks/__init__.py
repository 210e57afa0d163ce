"""Benchmarks (``python -m benchmarks.<name>``): print a table and write JSON.

Importing this package sets the CPU XLA flag MJX needs before JAX starts (see README). The compile cache stays
off here: benchmarks report compile time.
"""

from talar_jax.runtime import configure

configure(compile_cache=False)
