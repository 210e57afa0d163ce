"""The XLA flag MJX needs on a CPU, applied by the env library itself when it builds MJX physics.

XLA:CPU's fusion emitters compile MJX's deep kinematic chains into very slow-to-compile code: one kitchen MJX step
compiled in 50.7 s without ``--xla_cpu_use_fusion_emitters=false`` and in 28.4 s with it. XLA reads ``XLA_FLAGS``
once, when JAX initialises its backends (at the first computation, not at ``import jax``), so the flag can be added
to the environment until then and has no effect afterwards. ``prepare_mjx`` adds it while that is still possible and
otherwise warns once, naming the flag. The flag only concerns the CPU compiler, so adding it on a machine whose JAX
runs on an accelerator changes nothing there.

A program that steps no MJX physics (the C backend steps on the host, through a callback) has no such chains, and
the fusion emitters run its small dense layers and element-wise updates much faster: ``program_compiler_options``
turns them back on for that one program, whatever the process flag says.

Nothing here runs on import: importing ``envs`` never touches ``XLA_FLAGS``.
"""

from __future__ import annotations

import inspect
import os
import warnings
from pathlib import Path

CPU_XLA_FLAG = "--xla_cpu_use_fusion_emitters=false"
_FLAG_NAME = CPU_XLA_FLAG.split("=")[0]
_ENVS_DIR = str(Path(__file__).parent) + os.sep
_warned = False


def program_compiler_options(steps_mjx: bool) -> dict[str, bool]:
    """XLA options (``Lowered.compile(compiler_options=...)``) for a program that does (``steps_mjx``) or does not
    step MJX physics.

    Without MJX (C physics on the host through a callback, or no physics at all): the fusion emitters back on. The
    PPO learner's SGD (Table 2's 32-64-unit layers, one small kernel after another) ran 1.5x faster with them on a
    2-core CPU, and nothing in such a program has MJX's kinematic chains. With MJX: no override, the process flag
    stands. The option concerns only the CPU compiler; other backends ignore it.
    """
    return {} if steps_mjx else {_FLAG_NAME.removeprefix("--"): True}


def cpu_xla_flag_chosen() -> bool:
    """Whether ``XLA_FLAGS`` already says something about the fusion emitters (the flag above, or a user's own
    choice of the same option, which is left alone)."""
    return _FLAG_NAME in os.environ.get("XLA_FLAGS", "")


def backends_initialised() -> bool:
    """Whether JAX has created its backends (after which ``XLA_FLAGS`` is no longer read).

    JAX's public API has no query for this, but it documents one rule that shows it: ``jax_num_cpu_devices`` may
    change only before the backends start (``jax.config.update`` raises ``RuntimeError`` afterwards). So the probe
    asks for another value and, when that was still allowed, puts the old one straight back.
    """
    import jax

    current = jax.config.jax_num_cpu_devices
    try:
        jax.config.update("jax_num_cpu_devices", current + 1)
    except RuntimeError:
        return True
    jax.config.update("jax_num_cpu_devices", current)
    return False


def set_cpu_xla_flag() -> bool:
    """Adds ``CPU_XLA_FLAG`` to ``XLA_FLAGS`` unless it (or another value of its option) is there already, but only
    while JAX's backends are not initialised. Returns whether the option is in effect for this process."""
    if cpu_xla_flag_chosen():
        return True
    if backends_initialised():
        return False
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + CPU_XLA_FLAG).strip()
    return True


def _caller_stacklevel() -> int:
    """The ``warnings.warn`` stacklevel of the first frame outside this package, so the warning names the user's
    line (``make`` reaches here through the registry, the env class and the physics factory)."""
    frame, level = inspect.currentframe().f_back, 1
    while frame is not None and frame.f_code.co_filename.startswith(_ENVS_DIR):
        frame, level = frame.f_back, level + 1
    return level


def prepare_mjx() -> None:
    """Called whenever MJX physics is built: sets the CPU flag when still possible; when JAX already runs on a CPU
    without it, warns once per process (compiling MJX steps then takes about twice as long)."""
    global _warned
    if set_cpu_xla_flag() or _warned:
        return
    import jax

    if jax.default_backend() != "cpu":  # the flag only matters to XLA:CPU
        return
    _warned = True
    warnings.warn(
        f"MJX physics on a CPU without XLA_FLAGS={CPU_XLA_FLAG}: its steps take about twice as long to compile; "
        "set it in the environment, or build the env before JAX's first computation so envs sets it",
        stacklevel=_caller_stacklevel(),
    )
