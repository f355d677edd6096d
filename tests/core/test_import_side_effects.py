"""Importing hsa_core sets nothing global (jaxsetup's promise): every module is imported in a fresh
interpreter and the process-wide settings are compared before and after; controller_node's
parameter module reads no gains file at import."""

from __future__ import annotations

import json
import os
import subprocess
import sys

SNAPSHOT = r"""
import ast, importlib, importlib.util, json, logging, os, pkgutil, signal, sys, warnings
import jax
import matplotlib
import numpy as np


def snapshot():
    rc = matplotlib.rcParams
    return {
        "matplotlib rcParams": {k: repr(dict.__getitem__(rc, k)) for k in rc},
        "pyplot imported": "matplotlib.pyplot" in sys.modules,
        "jax config": {k: repr(v) for k, v in jax.config.values.items()},
        "signal handlers": {s.name: repr(signal.getsignal(s)) for s in signal.Signals
                            if s not in (signal.SIGKILL, signal.SIGSTOP)},
        "environment": dict(os.environ),
        "numpy errstate": np.geterr(),
        "numpy printoptions": {k: repr(v) for k, v in np.get_printoptions().items()},
        "root logger": [logging.getLogger().level, [repr(h) for h in logging.getLogger().handlers]],
        "warning filters": [repr(f) for f in warnings.filters],
        "excepthook": repr(sys.excepthook),
    }


import hsa_core
names = sorted(m.name for m in pkgutil.walk_packages(hsa_core.__path__, "hsa_core."))
# what third-party packages do on their own import (scipy adds warning filters) is not hsa_core's
for name in names:
    tree = ast.parse(open(importlib.util.find_spec(name).origin).read())
    for node in tree.body:
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            modules = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        else:
            continue
        for module in modules:
            if module.split(".")[0] not in ("hsa_core", "__future__"):
                try:
                    importlib.import_module(module)
                except ModuleNotFoundError:  # a name, not a submodule
                    pass
before = snapshot()
for name in names:
    importlib.import_module(name)
after = snapshot()
changed = {k: [before[k], after[k]] for k in before if before[k] != after[k]}
print(json.dumps({"modules": names, "changed": changed}))
"""

GAINS_READ = r"""
import json, sys
from hsa_core.controller.control import GAINS_DIR

opened = []


def audit(event, args):
    if event == "open" and str(args[0]).startswith(str(GAINS_DIR)):
        opened.append(str(args[0]))


sys.addaudithook(audit)
from hsa_controller_node import parameters
at_import = list(opened)
kp = {spec.name: spec.default for spec in parameters.SPECS}["kp"]
print(json.dumps({"at_import": at_import, "on_access": opened, "kp": kp}))
"""


def _run(script: str) -> dict:
    """Run ``script`` in a fresh interpreter (no MPLBACKEND from outside); its last line, parsed."""
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


def test_importing_every_hsa_core_module_changes_no_global_state() -> None:
    """No backend chosen, no JAX flag, no signal handler, no environment variable, no numpy,
    logging or warnings setting."""
    result = _run(SNAPSHOT)
    expected = {
        "hsa_core.analysis.plotting",
        "hsa_core.sim.playback",
        "hsa_core.apps.tune",
        "hsa_core.apps.robustness",
    }
    assert expected <= set(result["modules"])
    assert result["changed"] == {}


def test_the_gains_file_is_read_when_the_specs_are_first_asked_for_not_at_import() -> None:
    """Importing controller_node's parameters opens no gains file; SPECS then carries the paper's
    FPU gains (planning_and_control.md §3.6: K_p = 0.3 rad^2/(N m))."""
    result = _run(GAINS_READ)
    assert result["at_import"] == []
    assert any(path.endswith("fpu_psatid.yaml") for path in result["on_access"]), result
    assert result["kp"] == 0.3
