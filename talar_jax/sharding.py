"""Spreads the seed axis of batched training state over ``jax.devices()`` with ``jax.sharding``.

The same code runs on one CPU, one GPU or many devices: arrays whose leading (seed) axis divides evenly by the
device count are split along it, everything else is replicated; ``jax.jit`` then partitions the vmapped
computation accordingly. Multi-host runs call ``jax.distributed.initialize()`` first (see docs/recipe.md).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

SEED_AXIS = "seeds"


def seed_mesh(devices: list[jax.Device] | None = None) -> Mesh:
    """A 1-D mesh over all (or the given) devices, named ``"seeds"``."""
    return Mesh(np.asarray(devices if devices is not None else jax.devices()), (SEED_AXIS,))


def shard_seeds(tree: Any, num_seeds: int, mesh: Mesh | None = None) -> Any:
    """Places every array of ``tree`` whose leading axis has ``num_seeds`` entries split over the mesh.

    Arrays without that leading axis, or a seed count the device count does not divide, are replicated.
    """
    mesh = mesh if mesh is not None else seed_mesh()
    split = num_seeds % mesh.size == 0
    split_sharding = NamedSharding(mesh, PartitionSpec(SEED_AXIS))
    replicated = NamedSharding(mesh, PartitionSpec())

    def place(x):
        if not hasattr(x, "shape"):
            return x
        seeded = split and x.ndim >= 1 and x.shape[0] == num_seeds
        return jax.device_put(x, split_sharding if seeded else replicated)

    return jax.tree.map(place, tree)
