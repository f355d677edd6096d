"""JAX settings of hsa-ros, made by an explicit call at every entry point (importing hsa_core
changes nothing).

:func:`configure_jax` switches JAX to float64 (the model needs double precision, model.md §9.1),
runs small compiled calls on the calling thread (no hand-off to a dispatch thread: the per-tick
model calls of the nodes are microseconds long, benchmarks/results/model.json), and enables JAX's
persistent compilation cache, so that a process started a second time loads every compiled function,
small ones too, instead of compiling it again (directory: ``HSA_JAX_CACHE_DIR``, default
``~/.cache/hsa_ros/jax``; an empty string disables it). :func:`require` is the guard of the model's
entry (:func:`hsa_core.model.params.load_params`): a program that forgot the call fails with one
clear line instead of computing in float32. Nodes and programs that never touch the model (bridge,
sequencer, recorder, player, launcher) never import JAX; the driver does, for the parameter set's h
and φ_max.
"""

from __future__ import annotations

import os
from pathlib import Path


def configure_jax() -> None:
    """float64, synchronous CPU dispatch and the persistent compilation cache (see the module
    docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_cpu_enable_async_dispatch", False)
    cache = cache_dir()
    if cache is not None:
        jax.config.update("jax_compilation_cache_dir", str(cache))
        # the small ones add up at start
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def use_every_core() -> None:
    """One XLA CPU device per core, so that a batch split over ``jax.devices()``
    (``closed_loop.batch_rollout``) runs on all of them; a GPU backend is unaffected. Call it before
    the first JAX computation: where JAX already computes in this process (e.g. a test calling a
    CLI's main), or the user chose a count (``JAX_NUM_CPU_DEVICES``, or the host device count in
    ``XLA_FLAGS``), nothing changes."""
    import jax

    if (
        "JAX_NUM_CPU_DEVICES" in os.environ
        or "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
    ):
        return
    try:
        jax.config.update("jax_num_cpu_devices", os.cpu_count() or 1)
    except RuntimeError:  # backends already initialised: the process keeps its devices
        pass


def cache_dir() -> Path | None:
    """The persistent cache directory (``HSA_JAX_CACHE_DIR``, default ``~/.cache/hsa_ros/jax``),
    None if disabled."""
    cache = os.environ.get("HSA_JAX_CACHE_DIR", str(Path.home() / ".cache" / "hsa_ros" / "jax"))
    return Path(cache) if cache else None


def require() -> None:
    """Raise RuntimeError unless :func:`configure_jax` has run (JAX in float64)."""
    import jax

    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "JAX is not configured for hsa_core: call hsa_core.jaxsetup.configure_jax() at the "
            "entry point, before any model computation (the model needs float64)"
        )
