"""hsa_core.jaxsetup.use_every_core: the batched CLIs (hsa_tune, hsa_robustness) split their batch
over every core."""

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


@pytest.mark.parametrize(
    "when, user, expected",
    [
        ("early", {}, os.cpu_count()),
        ("late", {}, 1),
        (
            "early",
            {"XLA_FLAGS": "--xla_force_host_platform_device_count=3"},
            3,  # the user's own count wins
        ),
        ("early", {"JAX_NUM_CPU_DEVICES": "1"}, 1),
    ],
)
def test_one_cpu_device_per_core_unless_too_late_or_set(
    when: str, user: dict[str, str], expected: int
) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")}
    env.update({"JAX_PLATFORMS": "cpu", **user})
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, when], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == expected
