"""Gains from flat parameter values (hsa_core.control.gains_from_parameters, ee_gains_from_parameters, retune): the
parameter names and meanings of docs/nodes/hsa_controller_node.md."""

from __future__ import annotations

from types import SimpleNamespace

from hsa_core.control import (CollocatedGains, ControllerKind, EeIntegralGains, PidGains,
                              default_gains, ee_gains_from_parameters, gains_from_parameters, retune)

VALUES = {"kp": 0.2, "ki": 0.1, "kd": 0.01, "gamma": 50.0, "kp_pid": 8.0, "ki_pid": 90.0, "kd_pid": 0.3,
          "ee_ki": 0.25, "ee_e_on": 0.004, "ee_z_max": 0.02, "ee_reset_on_setpoint_change": True,
          "reset_integral_on_setpoint_change": True}


def test_each_law_takes_its_own_gains() -> None:
    collocated = CollocatedGains(kp=0.2, ki=0.1, kd=0.01, gamma=50.0)
    assert gains_from_parameters(ControllerKind.PSATID, VALUES) == collocated
    assert gains_from_parameters("psatid_gc", VALUES) == collocated  # both collocated laws share kp, ki, kd, gamma
    assert gains_from_parameters("pid", VALUES) == PidGains(kp=8.0, ki=90.0, kd=0.3)


def test_ee_integral_gains() -> None:
    assert ee_gains_from_parameters(VALUES) == EeIntegralGains(ki_ee=0.25, e_on=0.004, z_max=0.02,
                                                               reset_on_setpoint_change=True)


def test_retune_replaces_gains_and_keeps_the_extension_choice() -> None:
    without = SimpleNamespace(kind=ControllerKind.PID, gains=default_gains("pid"), ee_integral=None,
                              reset_integral_on_setpoint_change=False)
    retune(without, VALUES)
    assert without.gains == PidGains(kp=8.0, ki=90.0, kd=0.3) and without.ee_integral is None
    assert without.reset_integral_on_setpoint_change is True
    with_ee = SimpleNamespace(kind=ControllerKind.PSATID, gains=default_gains("psatid"), ee_integral=EeIntegralGains(),
                              reset_integral_on_setpoint_change=True)
    retune(with_ee, {**VALUES, "reset_integral_on_setpoint_change": False})
    assert with_ee.gains == CollocatedGains(kp=0.2, ki=0.1, kd=0.01, gamma=50.0)
    assert with_ee.ee_integral == EeIntegralGains(ki_ee=0.25, e_on=0.004, z_max=0.02, reset_on_setpoint_change=True)
    assert with_ee.reset_integral_on_setpoint_change is False
