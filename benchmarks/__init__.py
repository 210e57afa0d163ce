"""Benchmarks (``python -m benchmarks.<name>``): print a table and write JSON.

Importing this package sets the CPU XLA flag MJX needs before JAX starts (see README).
"""

import os

_FLAG = "--xla_cpu_use_fusion_emitters=false"
if _FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FLAG).strip()
