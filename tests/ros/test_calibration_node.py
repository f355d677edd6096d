"""calibration_node in a real simulated graph: sim_node (plant with known sigma_a_eq) → emulated bus
→ dynamixel_driver, sim mocap → mocap_bridge → kinematics_node (nominal sigma_a_eq = 1) →
calibration_node.

Ground truth by construction: the plant hangs at rest with sigma_a_eq = [1.03, 0.98] (sim_node
parameter, no noise); the service must return those values and write them into the parameter file in
use. While excitation_player drives a step through the driver, the service must refuse.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_core.model.params import CONFIG_DIR, load_params
from hsa_msgs.msg import PlanarActuation
from hsa_msgs.srv import CalibrateRestStrain
from tests.ros.conftest import start_process, stop_process, wait_for_line

pytestmark = [pytest.mark.ros, pytest.mark.slow]

TRUTH = [1.03, 0.98]


@pytest.fixture(scope="module")
def graph(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The simulated graph plus a calibration_node whose params_file is a copy of the FPU set;
    yields that file."""
    tmp = tmp_path_factory.mktemp("calibration")
    params_file = tmp / "robot.yaml"
    shutil.copy(CONFIG_DIR / "fpu.yaml", params_file)
    port = tmp / "ttyDXL"
    procs = {
        "sim": start_process(
            [
                find_executable("hsa_sim_node", "sim_node"),
                "--ros-args",
                "-p",
                f"port:={port}",
                "-p",
                f"sigma_a_eq:={TRUTH}",
            ]
        ),
        "bridge": start_process([find_executable("hsa_mocap_bridge", "mocap_bridge")]),
        "kinematics": start_process([find_executable("hsa_kinematics_node", "kinematics_node")]),
        "calibration": start_process(
            [
                find_executable("hsa_identification", "calibration_node"),
                "--ros-args",
                "-p",
                f"params_file:={params_file}",
            ]
        ),
    }
    try:
        for name in ("sim", "bridge", "kinematics", "calibration"):
            wait_for_line(procs[name], "ready", timeout=240.0)
        procs["driver"] = start_process(
            [
                find_executable("hsa_dynamixel_driver", "dynamixel_driver"),
                "--ros-args",
                "-p",
                f"port:={port}",
            ]
        )
        wait_for_line(procs["driver"], "torque on", timeout=60.0)
        yield params_file
    finally:
        for proc in procs.values():
            stop_process(proc)


def _call(node, request: CalibrateRestStrain.Request) -> CalibrateRestStrain.Response:
    """Call the service and return its answer."""
    client = node.create_client(CalibrateRestStrain, "/calibrate_rest_strain")
    assert client.wait_for_service(timeout_sec=20.0)
    response = client.call(request, timeout_sec=30.0)
    assert response is not None
    return response


def test_calibration_at_rest_recovers_the_plant_rest_strains_and_writes_the_file(
    graph, ros_node
) -> None:
    time.sleep(2.0)  # 1 s of states (the default window) after the driver holds phi = 0
    response = _call(
        ros_node, CalibrateRestStrain.Request(num_samples=0, write_parameter_file=False)
    )
    # the node may not have discovered the driver's phi_present yet, nor (on a loaded machine, where
    # the wall-clock graph runs late) have buffered the window's 200 states: both pass with time,
    # unlike a wrong answer
    deadline = time.monotonic() + 60.0
    while (
        "no actuation" in response.message or "not enough samples" in response.message
    ) and time.monotonic() < deadline:
        time.sleep(1.0)
        response = _call(
            ros_node, CalibrateRestStrain.Request(num_samples=0, write_parameter_file=False)
        )
    assert response.success, response.message
    response = _call(
        ros_node, CalibrateRestStrain.Request(num_samples=0, write_parameter_file=True)
    )
    assert response.success, response.message
    np.testing.assert_allclose(response.sigma_a_eq, TRUTH, rtol=0, atol=1e-6)
    assert np.all(np.asarray(response.sigma_a_eq_std) < 1e-6) and response.residual_rms < 1e-6
    assert response.samples_used == 200 and response.parameter_file == str(graph)
    written = load_params(graph)
    np.testing.assert_array_equal(np.asarray(written.sigma_a_eq), np.asarray(response.sigma_a_eq))
    np.testing.assert_array_equal(
        np.asarray(written.S_a_hat), np.asarray(load_params("fpu").S_a_hat)
    )

    too_many = _call(ros_node, CalibrateRestStrain.Request(num_samples=5000))
    assert not too_many.success and "not enough samples" in too_many.message


def test_calibration_is_refused_while_an_excitation_twists_the_robot(graph, ros_node) -> None:
    player = start_process(
        [
            find_executable("hsa_identification", "excitation_player"),
            "--ros-args",
            "-p",
            "kind:=step",
            "-p",
            "mode:=elongation",
            "-p",
            "level:=1.0",
            "-p",
            "t_step:=0.0",
            "-p",
            "duration:=4.0",
            "-p",
            "start_delay:=0.0",
            "-p",
            "final_hold:=0.5",
        ]
    )
    twisted: list[float] = []
    ros_node.create_subscription(
        PlanarActuation, "/phi_present", lambda m: twisted.append(float(np.min(m.phi))), qos.SENSOR
    )
    try:
        wait_for_line(player, "playing", timeout=60.0)
        deadline = time.monotonic() + 20.0
        while not (twisted and twisted[-1] > 0.1) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert twisted and twisted[-1] > 0.1, "the step did not reach the motors"
        response = _call(
            ros_node, CalibrateRestStrain.Request(num_samples=100, write_parameter_file=True)
        )
        assert not response.success and "not at rest" in response.message, response.message
        assert response.parameter_file == ""
        assert player.wait(timeout=30.0) == 0, "exit_on_finish did not end the player"
    finally:
        stop_process(player)
