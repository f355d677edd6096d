"""hsa_core: ROS-free model, planning, control and estimation for planar HSA robots.

Importing this package switches JAX to float64 (the model needs double precision, model.md §9.1), runs small
compiled calls on the calling thread (no hand-off to a dispatch thread: the per-tick model calls of the nodes are
microseconds long, benchmarks/results/model.json), and enables JAX's persistent compilation cache, so that a node
started a second time loads its compiled model instead of compiling it again (directory: ``HSA_JAX_CACHE_DIR``,
default ``~/.cache/hsa_ros/jax``; set it to an empty string to disable).
"""

import os
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_cpu_enable_async_dispatch", False)

_cache_dir = os.environ.get("HSA_JAX_CACHE_DIR", str(Path.home() / ".cache" / "hsa_ros" / "jax"))
if _cache_dir:
    jax.config.update("jax_compilation_cache_dir", _cache_dir)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)

__version__ = "0.1.0"
