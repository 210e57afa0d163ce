"""Experiment entry points (``python -m experiments.<name>``, or the ``talar-*`` commands of pyproject.toml).

Importing this package sets nothing up: each command's ``main()`` first calls ``talar_jax.runtime.start`` (the CPU XLA
flag MJX needs, JAX's persistent compilation cache, line-buffered progress output, the commit its records name).
"""
