"""Deterministic model results kept on disk beside JAX's compilation cache, so a second start skips
recomputing them.

The users: the planner's reachable polygon (a batch of static equilibria, most of a warm planner
start) and the world's initial state (the plant hanging at rest, 5 s of RK4 steps). An entry is
keyed by a name, the inputs' bytes (dtype, shape, values; parameter sets by all their fields) and
the source of ``hsa_core`` itself, so any change of the model code or of an input computes afresh.
The cache lives in ``<HSA_JAX_CACHE_DIR>/results`` and follows that setting (empty: no cache). A
missing, unreadable or foreign entry is recomputed, never trusted: it is only a start-up shortcut,
the values are the ones the computation returns.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Callable

import jax
import numpy as np

from hsa_core.jaxsetup import cache_dir

_PACKAGE = Path(__file__).resolve().parent


@lru_cache(maxsize=1)
def _source_digest() -> bytes:
    """SHA-256 of every module of hsa_core: a code change invalidates every entry."""
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        digest.update(path.relative_to(_PACKAGE).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.digest()


def key(name: str, *inputs: object) -> str:
    """Hex key of ``name`` and the inputs (arrays, numbers, strings, or pytrees of them such as
    HsaParams)."""
    digest = hashlib.sha256(_source_digest() + name.encode())
    for item in inputs:
        leaves, tree = jax.tree_util.tree_flatten(item)
        digest.update(str(tree).encode())
        for leaf in leaves:
            array = np.asarray(leaf)
            digest.update(f"{array.dtype.str}{array.shape}".encode() + array.tobytes())
    return digest.hexdigest()


def cached(
    name: str, inputs: tuple[object, ...], compute: Callable[[], dict[str, np.ndarray]]
) -> dict[str, np.ndarray]:
    """The arrays ``compute()`` returns for these inputs, from the cache when an entry exists
    (written if not)."""
    root = cache_dir()
    if root is None:
        return compute()
    path = root / "results" / f"{name}-{key(name, *inputs)}.npz"
    try:
        with np.load(path, allow_pickle=False) as entry:
            return {k: entry[k] for k in entry.files}
    except (OSError, ValueError):
        pass  # absent or unreadable: compute it
    arrays = {k: np.asarray(v) for k, v in compute().items()}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as tmp:
            np.savez(tmp, **arrays)
        os.replace(tmp.name, path)  # atomic: a concurrent start reads the whole entry or none
    except OSError:
        pass  # a read-only or full disk only costs the shortcut
    return arrays
