"""Process set-up shared by the entry points (experiments, benchmarks, tests): ``start()`` is the first thing a
command's ``main()`` does (nothing is set up on import); it must run before JAX's first computation.

- the CPU XLA flag MJX needs (deep kinematic chains otherwise compile into exponentially slow code);
- JAX's persistent compilation cache, so a rerun or a resumed run loads its programs instead of compiling them; one
  folder per host CPU (model and instruction-set flags), since XLA:CPU programs are compiled for the host's
  instruction set and a home folder shared by different machines would otherwise load programs the CPU cannot run
  (SIGILL);
- line-buffered stdout, so progress lines reach a log file as they are printed;
- MuJoCo's offscreen rendering through EGL when no display is available (``MUJOCO_GL=egl`` unless set). MuJoCo
  reads the variable when it is imported, which a command has already done by the time its ``main()`` runs: then its
  OpenGL context module is loaded again so that the renderer takes EGL;
- XLA's C++ log at errors only (``TF_CPP_MIN_LOG_LEVEL=2`` unless set): loading a cached program otherwise prints a
  version-compatibility warning on every run. jaxlib reads the variable when it loads, and importing jax sets it to
  "1" when unset; once jax is imported, "1" is taken for that default and the level is set directly. On AVX-512
  hosts jaxlib 0.9 still logs, at error level, that a cached program's ``+prefer-no-gather`` /
  ``+prefer-no-scatter`` are not host features (jax-ml/jax#38445: LLVM tuning hints XLA adds on such hosts); the
  program loads and runs, and hiding every error-level log would hide real ones.
"""

from __future__ import annotations

import hashlib
import importlib
import logging
import os
import platform
import sys

from envs.runtime import CPU_XLA_FLAG, set_cpu_xla_flag

__all__ = ["CPU_XLA_FLAG", "compile_cache_dir", "configure", "host_cpu_fingerprint", "start"]

# Its own variable: $TALAR_JAX_CACHE names the language cache folder itself (talar_jax.language.cache).
COMPILE_CACHE_ENV_VAR = "TALAR_JAX_COMPILE_CACHE"
COMPILE_CACHE_DIR = "~/.cache/talar-jax/jax"


def host_cpu_fingerprint(cpuinfo: str | None = None) -> str:
    """A short hash of the CPU model and instruction-set flags (``/proc/cpuinfo``; the platform string elsewhere)."""
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo") as f:
                cpuinfo = f.read()
        except OSError:
            cpuinfo = ""
    wanted = ("model name", "flags", "features", "cpu model")
    lines = sorted(
        {line.split(":", 1)[1].strip() for line in cpuinfo.splitlines() if line.split(":")[0].strip().lower() in wanted}
    )
    text = "\n".join([platform.machine(), *lines]) if lines else platform.platform()
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def compile_cache_dir() -> str:
    """This host's folder of JAX's persistent compilation cache."""
    root = os.environ.get(COMPILE_CACHE_ENV_VAR) or COMPILE_CACHE_DIR
    return os.path.join(os.path.expanduser(root), host_cpu_fingerprint())


def _quiet_xla_log() -> None:
    """XLA's C++ log at errors only, unless ``TF_CPP_MIN_LOG_LEVEL`` asks otherwise (see the module docstring)."""
    if "jax" not in sys.modules:
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    elif os.environ.get("TF_CPP_MIN_LOG_LEVEL") == "1":  # jax's default, already read by jaxlib
        os.environ["TF_CPP_MIN_LOG_LEVEL"] = "2"
        _cpp_log_at_errors()


def _cpp_log_at_errors() -> None:
    """XLA's C++ log at errors only, through JAX's public switch ``jax_logging_level`` (whose "ERROR" sets the C++
    minimum level to 2). The switch also gives the Python ``jax`` and ``jaxlib`` loggers that level and a handler of
    its own; both are put back, so that JAX's Python warnings show as they did."""
    import jax

    loggers = [logging.getLogger(name) for name in ("jax", "jaxlib")]
    kept = [(logger, logger.level, list(logger.handlers)) for logger in loggers]
    jax.config.update("jax_logging_level", "ERROR")
    for logger, level, handlers in kept:
        logger.setLevel(level)
        for handler in [handler for handler in logger.handlers if handler not in handlers]:
            logger.removeHandler(handler)


def _select_mujoco_gl() -> None:
    """``MUJOCO_GL=egl`` when there is no display and the variable is unset; when MuJoCo is already imported, its
    OpenGL context module (which read the variable on import) is loaded again, so ``mujoco.Renderer`` uses EGL."""
    if os.environ.get("DISPLAY") or "MUJOCO_GL" in os.environ:
        return
    os.environ["MUJOCO_GL"] = "egl"
    for name in ("mujoco.rendering.classic.gl_context", "mujoco.gl_context"):  # mujoco 4 / mujoco 3 layouts
        module = sys.modules.get(name)
        if module is not None:
            importlib.reload(module)
            if hasattr(module, "GLContext"):
                sys.modules["mujoco"].GLContext = module.GLContext


def configure(compile_cache: bool = True) -> None:
    """Sets the XLA flag and log level (when JAX has not started yet), the compile cache and line-buffered stdout.

    Safe to call again. JAX does not cache programs that call back into Python, which includes every program stepping
    the C physics: those compile again in each process.
    """
    _quiet_xla_log()
    _select_mujoco_gl()
    set_cpu_xla_flag()  # the envs' own rule: only while JAX has not started, never over a user's own value
    if compile_cache:
        import jax

        jax.config.update("jax_compilation_cache_dir", compile_cache_dir())
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    if hasattr(sys.stdout, "reconfigure") and not sys.stdout.isatty():
        sys.stdout.reconfigure(line_buffering=True)


def start(compile_cache: bool = True) -> None:
    """What a command does first: ``configure`` the process, and read the checkout's commit that the run's records
    name (``talar_jax.provenance.process_commit``), so that a run whose checkout moves on while it trains still names
    the code it started with."""
    configure(compile_cache)
    from talar_jax.provenance import process_commit

    process_commit()
