"""hsa_core.jaxsetup.use_every_core: the batched CLIs (hsa_tune, hsa_robustness) split their batch over every core."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

SCRIPT = """
import json, os, sys
import jax
from hsa_core.jaxsetup import configure_jax, use_every_core
configure_jax()
if sys.argv[1] == "late":
    jax.numpy.zeros(1).block_until_ready()  # JAX already computes: its devices stay
use_every_core()
print(json.dumps(len(jax.devices())))
"""


@pytest.mark.parametrize("when, xla_flags, expected", [
    ("early", "", os.cpu_count()),
    ("late", "", 1),
    ("early", "--xla_force_host_platform_device_count=3", 3),  # the user's own count wins
])
def test_one_cpu_device_per_core_unless_too_late_or_set(when: str, xla_flags: str, expected: int) -> None:
    env = {**os.environ, "XLA_FLAGS": xla_flags, "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", SCRIPT, when], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == expected
