"""controller_node's messages: converters between hsa_msgs and arrays, and the phi_cmd and controller_info it sends."""

from __future__ import annotations

import copy
import math

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from rclpy.time import Time

from hsa_core.control import ControllerState
from hsa_core.control_loop import Command, Tick
from hsa_core.supervision import Mode
from hsa_msgs.msg import ControllerInfo, CsConfiguration, PlanarActuation, PlanarPose, Setpoint

FRAME_ID = "hsa_base"
INFO_STATE = {
    Mode.WAITING_FOR_SETPOINT: ControllerInfo.STATE_WAITING_FOR_SETPOINT, Mode.TRACKING: ControllerInfo.STATE_TRACKING,
    Mode.HOLD: ControllerInfo.STATE_HOLD_STALE, Mode.ESTOP: ControllerInfo.STATE_STOPPED,
    **{m: ControllerInfo.STATE_WAITING_FOR_STATE
       for m in (Mode.WAITING_FOR_DRIVER, Mode.WAITING_FOR_STATE, Mode.STALE, Mode.DRIVER_LOST)},
}
"""controller_info state of each mode (hsa_msgs has no driver constants: those ticks send nothing, as WAITING_FOR_STATE)."""
NOTHING_SENT = np.full(2, math.nan)
"""φ fields of the info on ticks that send no command."""


def q_of(msg: CsConfiguration) -> np.ndarray:
    """[kappa_be, sigma_sh, sigma_ax] of a CsConfiguration."""
    return np.array([msg.kappa_be, msg.sigma_sh, msg.sigma_ax])


def pose_of(msg: PlanarPose) -> np.ndarray:
    """[x, y, theta] of a PlanarPose."""
    return np.array([msg.x, msg.y, msg.theta])


def q_msg(q: np.ndarray) -> CsConfiguration:
    """CsConfiguration of [kappa_be, sigma_sh, sigma_ax]."""
    return CsConfiguration(kappa_be=float(q[0]), sigma_sh=float(q[1]), sigma_ax=float(q[2]))


def pose_msg(chiee: np.ndarray) -> PlanarPose:
    """PlanarPose of [x, y, theta]."""
    return PlanarPose(x=float(chiee[0]), y=float(chiee[1]), theta=float(chiee[2]))


def stamp_msg(ns: int) -> TimeMsg:
    """builtin_interfaces/Time of int nanoseconds."""
    return Time(nanoseconds=ns).to_msg()


def command_msg(command: Command, now: Time) -> PlanarActuation:
    """phi_cmd of a command sent at now; source_stamp is the stamp of the state it was computed from."""
    cmd = PlanarActuation(phi=command.phi)
    cmd.header.stamp, cmd.header.frame_id = now.to_msg(), FRAME_ID
    cmd.source_stamp = stamp_msg(command.source_stamp_ns)
    return cmd


def tracking_info(tick: Tick, now: Time, controller: str, setpoint: Setpoint | None,
                  motor_goal_angles: np.ndarray) -> ControllerInfo:
    """controller_info of a tracking tick: every field, from the law's quantities and the state stepped on."""
    info, source_ns = tick.info, tick.command.source_stamp_ns
    out = ControllerInfo(
        state_stamp=stamp_msg(source_ns), controller=controller, state=ControllerInfo.STATE_TRACKING,
        setpoint=setpoint, chiee=pose_msg(info.chiee), chiee_des=pose_msg(info.chiee_des), q=q_msg(info.q),
        q_des=q_msg(info.q_des), q_dot=q_msg(tick.measurement.q_dot), varphi=info.varphi,
        varphi_des=info.varphi_des, e_int=info.e_int, z_ee=info.z_ee, phi_ss=info.phi_ss,
        phi_des_unsat=info.phi_des_unsat, phi_des_sat=info.phi_des_sat, motor_goal_angles=motor_goal_angles,
        saturated=bool(info.saturated), state_age=(now.nanoseconds - source_ns) * 1e-9, compute_time=tick.compute_s,
    )
    out.header.stamp, out.header.frame_id = now.to_msg(), FRAME_ID
    return out


def repeated_info(last: ControllerInfo, now: Time, state: int, setpoint: Setpoint | None,
                  integrators: ControllerState, commanded: bool) -> ControllerInfo:
    """Info of a tick without a step: the last tracking tick's fields with this tick's state, stamp, setpoint and
    integrator state; φ fields NaN when nothing is sent."""
    info = copy.deepcopy(last)
    info.header.stamp, info.state, info.compute_time = now.to_msg(), state, 0.0
    info.setpoint = setpoint
    info.state_age = (now - Time.from_msg(info.state_stamp)).nanoseconds * 1e-9
    info.e_int, info.z_ee = integrators.e_int, integrators.z_ee
    if not commanded:
        info.phi_des_unsat, info.phi_des_sat = NOTHING_SENT, NOTHING_SENT
        info.motor_goal_angles = np.full(4, math.nan)
        info.saturated = False
    return info
