"""controller_node's messages: the phi_cmd and controller_info it sends (conversions:
hsa_common.convert)."""

from __future__ import annotations

import copy
import math

import numpy as np
from rclpy.time import Time

from hsa_common import convert
from hsa_core.controller.control import ControllerState
from hsa_core.controller.control_loop import Command, Tick
from hsa_core.controller.supervision import Mode
from hsa_msgs.msg import ControllerInfo, PlanarActuation, Setpoint

FRAME_ID = "hsa_base"
INFO_STATE = {
    Mode.WAITING_FOR_SETPOINT: ControllerInfo.STATE_WAITING_FOR_SETPOINT,
    Mode.TRACKING: ControllerInfo.STATE_TRACKING,
    Mode.HOLD: ControllerInfo.STATE_HOLD_STALE,
    Mode.ESTOP: ControllerInfo.STATE_STOPPED,
    Mode.TORQUE_OFF: ControllerInfo.STATE_TORQUE_OFF,
    **{
        m: ControllerInfo.STATE_WAITING_FOR_STATE
        for m in (Mode.WAITING_FOR_DRIVER, Mode.WAITING_FOR_STATE, Mode.STALE, Mode.DRIVER_LOST)
    },
}
"""controller_info state of each mode (the other driver modes send nothing, as
WAITING_FOR_STATE)."""
NOTHING_SENT = np.full(2, math.nan)
"""φ fields of the info on ticks that send no command."""


def command_msg(command: Command, now: Time) -> PlanarActuation:
    """phi_cmd of a command sent at now; source_stamp is the stamp of the state it was computed
    from."""
    return convert.actuation_msg(
        command.phi, now.to_msg(), FRAME_ID, convert.stamp_msg(command.source_stamp_ns)
    )


def tracking_info(
    tick: Tick, now: Time, controller: str, setpoint: Setpoint | None, motor_goal_angles: np.ndarray
) -> ControllerInfo:
    """controller_info of a tracking tick: every field, from the law's quantities and the state
    stepped on."""
    info, source_ns = tick.info, tick.command.source_stamp_ns
    out = ControllerInfo(
        state_stamp=convert.stamp_msg(source_ns),
        controller=controller,
        state=ControllerInfo.STATE_TRACKING,
        setpoint=setpoint,
        chiee=convert.planar_pose_msg(info.chiee),
        chiee_des=convert.planar_pose_msg(info.chiee_des),
        q=convert.configuration_msg(info.q),
        q_des=convert.configuration_msg(info.q_des),
        q_dot=convert.configuration_msg(tick.measurement.q_dot),
        varphi=info.varphi,
        varphi_des=info.varphi_des,
        e_int=info.e_int,
        z_ee=info.z_ee,
        phi_ss=info.phi_ss,
        phi_des_unsat=info.phi_des_unsat,
        phi_des_sat=info.phi_des_sat,
        motor_goal_angles=motor_goal_angles,
        saturated=bool(info.saturated),
        state_age=(now.nanoseconds - source_ns) * 1e-9,
        compute_time=tick.compute_s,
    )
    out.header.stamp, out.header.frame_id = now.to_msg(), FRAME_ID
    return out


def repeated_info(
    last: ControllerInfo,
    now: Time,
    state: int,
    setpoint: Setpoint | None,
    integrators: ControllerState,
    commanded: bool,
) -> ControllerInfo:
    """Info of a tick without a step: the last tracking tick's fields with this tick's state, stamp,
    setpoint and integrator state; φ fields NaN when nothing is sent."""
    info = copy.deepcopy(last)
    info.header.stamp, info.state, info.compute_time = now.to_msg(), state, 0.0
    info.setpoint = setpoint
    info.state_age = (now.nanoseconds - convert.stamp_ns(info.state_stamp)) * 1e-9
    info.e_int, info.z_ee = integrators.e_int, integrators.z_ee
    if not commanded:
        info.phi_des_unsat, info.phi_des_sat = NOTHING_SENT, NOTHING_SENT
        info.motor_goal_angles = np.full(4, math.nan)
        info.saturated = False
    return info
