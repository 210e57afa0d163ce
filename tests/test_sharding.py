"""Seed sharding: with several devices the seed axis is split across them and results do not change."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np

from talar_jax.sharding import shard_seeds


def test_single_device_is_a_no_op_on_values():
    tree = {"w": jnp.arange(6.0).reshape(3, 2), "scalar": jnp.ones(())}
    placed = shard_seeds(tree, num_seeds=3)
    np.testing.assert_array_equal(placed["w"], tree["w"])


def test_seed_axis_is_split_over_two_host_devices():
    code = textwrap.dedent(
        """
        import jax, jax.numpy as jnp, numpy as np
        from talar_jax.sharding import shard_seeds
        assert len(jax.devices()) == 2, jax.devices()
        keys = jax.random.split(jax.random.key(0), 4)
        data = jax.vmap(lambda k: jax.random.normal(k, (8,)))(keys)
        placed = shard_seeds({"x": data, "shared": jnp.ones(3)}, num_seeds=4)
        assert len(placed["x"].sharding.device_set) == 2
        out = jax.jit(jax.vmap(lambda x: (x ** 2).sum()))(placed["x"])
        assert len(out.sharding.device_set) == 2
        np.testing.assert_allclose(out, (np.asarray(data) ** 2).sum(1), rtol=1e-6)
        odd = shard_seeds({"x": data[:3]}, num_seeds=3)  # 3 seeds on 2 devices: replicated, still correct
        assert odd["x"].sharding.is_fully_replicated
        print("ok")
        """
    )
    env = {**os.environ, "XLA_FLAGS": os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), result.stderr[-2000:]
    assert jax.devices()  # the parent process is unaffected
