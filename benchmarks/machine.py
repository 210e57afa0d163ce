"""What a benchmark ran on: written beside its numbers, since the same command gives other seconds elsewhere."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import jax


def machine_info() -> dict[str, object]:
    """Platform, CPU model and count, the vector extensions that change XLA's CPU speed, JAX's backend."""
    model, flags = platform.processor() or platform.machine(), set()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name") and ":" in line:
                model = line.split(":", 1)[1].strip()
            elif line.startswith("flags") and ":" in line:
                flags = set(line.split(":", 1)[1].split())
                break
    return {
        "platform": platform.platform(),
        "cpu": model,
        "cpu_count": os.cpu_count(),
        "vector_extensions": sorted(flags & {"avx2", "avx512f", "amx_tile"}),
        "jax_backend": jax.default_backend(),
        # e.g. --xla_cpu_max_isa=AVX2 measures, on an AVX-512 machine, what XLA's code does without AVX-512
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "jax_devices": jax.local_device_count(),
    }
