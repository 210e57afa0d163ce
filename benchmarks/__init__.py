"""Benchmarks (``python -m benchmarks.<name>``): print a table and write JSON.

Importing this package sets nothing up: each benchmark's ``main()`` first calls ``talar_jax.runtime.configure`` (the
CPU XLA flag MJX needs, before JAX starts; see docs/environments.md). Most keep the compile cache off, since they
report compile time.
"""
