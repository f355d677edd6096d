"""Gains from controller_node's flat parameter values (hsa_controller_node.parameters: gains,
ee_gains, tuning) as the typed objects hsa_core takes (hsa_core.controller.control.Tuning, retune):
the parameter names and meanings of docs/nodes/hsa_controller_node.md."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from hsa_common.parameters import ParameterValidationError, typed
from hsa_controller_node.parameters import ee_gains, gains, tuning
from hsa_core.controller.control import (
    CollocatedGains,
    ControllerKind,
    EeIntegralGains,
    PidGains,
    Tuning,
    default_gains,
    retune,
)
from hsa_core.controller.supervision import SupervisorConfig

VALUES = {
    "kp": 0.2,
    "ki": 0.1,
    "kd": 0.01,
    "gamma": 50.0,
    "kp_pid": 8.0,
    "ki_pid": 90.0,
    "kd_pid": 0.3,
    "ee_ki": 0.25,
    "ee_e_on": 0.004,
    "ee_z_max": 0.02,
    "ee_reset_on_setpoint_change": True,
    "reset_integral_on_setpoint_change": True,
}


def test_each_law_takes_its_own_gains() -> None:
    collocated = CollocatedGains(kp=0.2, ki=0.1, kd=0.01, gamma=50.0)
    assert gains(ControllerKind.PSATID, VALUES) == collocated
    assert gains(ControllerKind.PSATID_GC, VALUES) == collocated  # both collocated laws share them
    assert gains(ControllerKind.PID, VALUES) == PidGains(kp=8.0, ki=90.0, kd=0.3)


def test_ee_integral_gains() -> None:
    assert ee_gains(VALUES) == EeIntegralGains(
        ki_ee=0.25, e_on=0.004, z_max=0.02, reset_on_setpoint_change=True
    )


def test_retune_replaces_gains_and_keeps_the_extension_choice() -> None:
    without = SimpleNamespace(
        kind=ControllerKind.PID,
        gains=default_gains("pid"),
        ee_integral=None,
        reset_integral_on_setpoint_change=False,
    )
    retune(without, tuning(ControllerKind.PID, VALUES))
    assert without.gains == PidGains(kp=8.0, ki=90.0, kd=0.3) and without.ee_integral is None
    assert without.reset_integral_on_setpoint_change is True
    with_ee = SimpleNamespace(
        kind=ControllerKind.PSATID,
        gains=default_gains("psatid"),
        ee_integral=EeIntegralGains(),
        reset_integral_on_setpoint_change=True,
    )
    kept = {**VALUES, "reset_integral_on_setpoint_change": False}
    retune(with_ee, tuning(ControllerKind.PSATID, kept))
    assert with_ee.gains == CollocatedGains(kp=0.2, ki=0.1, kd=0.01, gamma=50.0)
    assert with_ee.ee_integral == EeIntegralGains(
        ki_ee=0.25, e_on=0.004, z_max=0.02, reset_on_setpoint_change=True
    )
    assert with_ee.reset_integral_on_setpoint_change is False


def test_bad_gains_are_refused_in_one_line_naming_them() -> None:
    """The typed objects check themselves; the node shell's error names the parameters."""
    gamma = r"^gain 'gamma' of CollocatedGains must be finite and > 0, got 0.0$"
    with pytest.raises(ValueError, match=gamma):
        Tuning(CollocatedGains(0.3, 0.05, 0.02, 0.0), EeIntegralGains(), False)
    e_on = r"^controller gains: gain 'e_on' of EeIntegralGains"
    with pytest.raises(ParameterValidationError, match=e_on):
        tuning(ControllerKind.PSATID, {**VALUES, "ee_e_on": 0.0})
    with pytest.raises(ValueError, match=r"^controller 'pid' needs PidGains, got CollocatedGains$"):
        retune(SimpleNamespace(kind=ControllerKind.PID), tuning(ControllerKind.PSATID, VALUES))


def test_typed_builds_the_dataclass_from_parameters_and_names_them_on_refusal() -> None:
    good = {
        "stale_timeout": 0.1,
        "hold_timeout": 0.25,
        "driver_timeout": 0.0,
        "stamp_clock": False,
        "rate": 40.0,  # parameters the class does not take are left alone
    }
    assert typed(SupervisorConfig, good) == SupervisorConfig(0.1, 0.25, 0.0, False)
    with pytest.raises(ParameterValidationError) as error:
        typed(SupervisorConfig, {**good, "hold_timeout": 0.05})
    assert str(error.value) == (
        "parameters ['driver_timeout', 'hold_timeout', 'stale_timeout', "
        "'stamp_clock']: need 0 < stale_timeout <= hold_timeout, got 0.1, "
        "0.05"
    )
