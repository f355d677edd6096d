"""hsa_core.model.wiring: the robot's wiring file (planning_and_control.md §7) and the motor map
built from it."""

from __future__ import annotations

import math
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from hsa_core.controller import control
from hsa_core.model.params import load_params
from hsa_core.model.wiring import WiringError, load_wiring


def test_packaged_lab_robot_is_the_spec_wiring() -> None:
    """Spec §7: motors 21/22 drive rod 2, 23/24 rod 1; ψ = [+φ₂, −φ₂, +φ₁, −φ₁]; power-on neutral
    2048."""
    wiring = load_wiring()
    assert wiring.motor_ids == (21, 22, 23, 24)
    assert wiring.neutral_ticks == (2048,) * 4
    psi = wiring.motor_map(load_params("fpu")).motor_angles([0.1, 0.7])
    np.testing.assert_allclose(psi, [0.7, -0.7, 0.1, -0.1])
    assert load_wiring("lab") == wiring


@pytest.mark.parametrize("material, degrees", [("fpu", 200.0), ("epu", 270.0)])
def test_twist_limit_and_handedness_come_from_the_parameter_set(
    material: str, degrees: float
) -> None:
    """φ_max of the map is the material's (FPU 200°, EPU 270°: the packaged sets); h from the set,
    not the file."""
    params = load_params(material)
    motor_map = load_wiring().motor_map(params, margin=0.0)
    assert motor_map.phi_max == pytest.approx(math.radians(degrees))
    flipped = params.replace(h=[-1.0, 1.0])
    np.testing.assert_allclose(
        load_wiring().motor_map(flipped).motor_angles([0.1, 0.7]), [0.7, -0.7, -0.1, 0.1]
    )


def test_one_phi_limit_gives_the_box_the_command_clip_and_the_motor_bound() -> None:
    """PhiLimit, made from the parameter set, is what the planner/validator box, the laws' clip and
    the motor map read: rods with different limits and handedness show each view."""
    params = load_params("fpu").replace(phi_max=[2.0, 3.0], h=[-1.0, 1.0])
    limit = params.phi_limit
    lo, hi = limit.box
    np.testing.assert_array_equal(lo, [-2.0, 0.0])
    np.testing.assert_array_equal(hi, [0.0, 3.0])
    np.testing.assert_array_equal(np.asarray(limit.clip(np.array([2.5, 2.5]))), [2.0, 2.5])
    np.testing.assert_array_equal(np.asarray(limit.clip(np.array([-0.1, 4.0]))), [0.0, 3.0])
    assert limit.motor == 2.0 and limit.handedness == (-1, 1)
    motor_map = load_wiring().motor_map(params)
    assert motor_map.phi_max == limit.motor and motor_map.h == limit.handedness
    phi_cmd, saturated = control._saturate(params, jnp.array([-2.5, 1.0]))  # clip(h φ^d, 0, φ_max)
    np.testing.assert_array_equal(np.asarray(phi_cmd), [2.0, 1.0])
    assert bool(saturated)


def test_given_neutral_overrides_the_nominal() -> None:
    motor_map = load_wiring().motor_map(load_params("fpu"), neutral_ticks=(1000, 3000, -500, 5000))
    assert motor_map.goal_ticks([0.0, 0.0]).tolist() == [1000, 3000, -500, 5000]


@pytest.mark.parametrize(
    "text, key",
    [
        (
            "motor_ids: [1, 2, 3]\nrod: [1, 1, 0, 0]\nrho: [1, -1, 1, -1]\nneutral_ticks: [0, 0, "
            "0, 0]\n",
            "one distinct",
        ),
        (
            "motor_ids: [1, 1, 3, 4]\nrod: [1, 1, 0, 0]\nrho: [1, -1, 1, -1]\nneutral_ticks: [0, "
            "0, 0, 0]\n",
            "distinct",
        ),
        (
            "motor_ids: [1, 2, 3, 4]\nrod: [1, 1, 0, 0]\nrho: [1, -2, 1, -1]\nneutral_ticks: [0, "
            "0, 0, 0]\n",
            "+1 or -1",
        ),
        (
            "motor_ids: [1, 2, 3, 4]\nrod: [1, 1, 1, 1]\nrho: [1, -1, 1, -1]\nneutral_ticks: [0, "
            "0, 0, 0]\n",
            "every rod",
        ),
        (
            "motor_ids: [1, 2, 3, 400]\nrod: [1, 1, 0, 0]\nrho: [1, -1, 1, -1]\nneutral_ticks: [0, "
            "0, 0, 0]\n",
            "0 … 252",
        ),
        ("motor_ids: [1, 2, 3, 4]\nrod: [1, 1, 0, 0]\nrho: [1, -1, 1, -1]\n", "'neutral_ticks'"),
        (
            "motor_ids: [1, 2, 3, 4.5]\nrod: [1, 1, 0, 0]\nrho: [1, -1, 1, -1]\nneutral_ticks: [0, "
            "0, 0, 0]\n",
            "integers",
        ),
        (
            "motor_ids: [1, 2, 3, 4]\nrod: [1, 1, 0, 0]\nrho: [1, -1, 1, -1]\nneutral_ticks: [0, "
            "0, 0, 0]\nh: [1, 1]\n",
            "unknown key 'h'",
        ),
        ("- 1\n", "mapping"),
    ],
)
def test_bad_files_are_refused_naming_the_problem(tmp_path: Path, text: str, key: str) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    with pytest.raises(WiringError, match=re.escape(key)) as info:
        load_wiring(path)
    assert str(path) in str(info.value)


def test_missing_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(WiringError, match="cannot be read"):
        load_wiring(tmp_path / "absent.yaml")
