"""Fixtures for tests that run real rclpy processes: process groups, and an rclpy node in the test
process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest
import rclpy
import yaml
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.client import Client
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python

from hsa_common import rosenv
from hsa_common.launcher import STUCK, find_executable
from hsa_core.task.trajectories import step_reference

PEERS = Path(__file__).parent / "peers"
LAUNCHER = (sys.executable, "-m", "hsa_common.launcher")
"""hsa_launch as the tests run it."""
GRAPH_STOP = ("--sigterm-timeout", "20")
"""Launcher options of a test whose graph must end cleanly (exit 0): its nodes get 20 s, not 5,
between SIGINT and SIGTERM. They tear down at nice 5 (hsa_common.runner.TEARDOWN_NICE), and beside
two busy processes a bridge, a planner and a sequencer each once outlasted SIGINT + 5 s + SIGTERM +
5 s and were SIGKILLed (launcher exit 137). Some of those may have been a hang rather than a slow
teardown: the runner's stop handler could deadlock on a second signal until session 30
(docs/launch.md, "Teardown bounds")."""
SIM_GRAPH = Path(__file__).parents[2] / "launch_scripts" / "sim.launch.yaml"
SIM_STEPS, SIM_STEP_PERIOD = 3, 2.0
"""The schedule of the session's sim run (sim_step_bag): the first FPU steps, s per setpoint."""


def launcher_story(output: str, tail: int = 4000) -> str:
    """What a failed launch's output says: from where the launcher reports a process stuck in its
    stop (its threads and stacks, hsa_common.stacks) to the end, else the last ``tail``
    characters."""
    stuck = output.find(STUCK)
    return output[output.rfind("\n", 0, stuck) + 1 :] if stuck >= 0 else output[-tail:]


def start_process(args: list[str], **popen: object) -> subprocess.Popen:
    """Start a ROS process in its own session with the project ROS environment (stop it with
    stop_process)."""
    return subprocess.Popen(
        args,
        env=rosenv.ros_environment(),
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        **popen,
    )


def start_node(
    package: str, executable: str, params: Sequence[str], remaps: Sequence[str] = ("__ns:=/hsa",)
) -> subprocess.Popen:
    """A node process (start_process) with ``-r`` remaps (default: namespace /hsa) and
    ``-p name:=value`` parameters."""
    args = ["--ros-args"]
    for remap in remaps:
        args += ["-r", remap]
    for param in params:
        args += ["-p", param]
    return start_process([find_executable(package, executable), *args])


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> int:
    """SIGINT the process group, escalating to SIGTERM and SIGKILL after timeouts; return the exit
    code."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        if proc.poll() is not None:
            break
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            continue
    return proc.wait()


def assert_refused_at_start(procs: dict[str, subprocess.Popen], timeout: float = 120.0) -> None:
    """Each process (keyed by a parameter's name) exits 2 saying "refusing to start", naming it."""
    for name, proc in procs.items():
        try:
            out, _ = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            stop_process(proc)
            out, _ = proc.communicate()
        assert proc.returncode == 2, out
        assert "refusing to start" in out and f"'{name}'" in out, out


def wait_for_line(proc: subprocess.Popen, text: str, timeout: float = 60.0) -> list[str]:
    """Read the process output until a line contains ``text``; fail with the output so far on
    timeout or exit."""
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                break
            continue
        lines.append(line)
        if text in line:
            return lines
    pytest.fail(f"{text!r} not seen from {proc.args} (exit {proc.poll()}):\n{''.join(lines)}")


@pytest.fixture
def peer() -> Iterator[Callable[[str], subprocess.Popen]]:
    """Start peer scripts from tests/ros/peers by name; all are stopped at teardown."""
    procs: list[subprocess.Popen] = []

    def _start(name: str, *args: str) -> subprocess.Popen:
        proc = start_process([sys.executable, str(PEERS / f"{name}.py"), *args])
        procs.append(proc)
        wait_for_line(proc, "ready")
        return proc

    yield _start
    for proc in procs:
        stop_process(proc)


@pytest.fixture
def ros_node() -> Iterator[Node]:
    """An rclpy node in the test process, spun by a background executor thread."""
    rclpy.init()
    node = rclpy.create_node("test_probe")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield node
    finally:
        executor.shutdown()
        thread.join(timeout=5)
        node.destroy_node()
        rclpy.try_shutdown()


def wait_until(
    condition: Callable[[], object],
    timeout: float = 20.0,
    step: Callable[[], None] | None = None,
    poll: float = 0.01,
) -> bool:
    """Poll ``condition`` (calling ``step`` between polls) until it holds or ``timeout`` s pass;
    return whether it held."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        if step is not None:
            step()
        time.sleep(poll)
    return bool(condition())


class CollectedProcess:
    """A started process whose output is collected by a reader thread once it has logged
    ``ready``."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self.lines: list[str] = []
        self._reader: threading.Thread | None = None

    def wait_ready(self, timeout: float = 180.0) -> CollectedProcess:
        """Block until the node logged ``ready``, then keep reading its output in the background."""
        self.lines += wait_for_line(self.proc, "ready", timeout)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        return self

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)

    def log(self, text: str) -> list[str]:
        """Output lines containing ``text``."""
        return [line for line in list(self.lines) if text in line]

    def output(self) -> str:
        """Everything the process printed so far."""
        return "".join(self.lines)

    def wait_exit(self, timeout: float = 20.0) -> int:
        """The exit code once the process ended by itself (its output fully read)."""
        code = self.proc.wait(timeout=timeout)
        if self._reader is not None:
            self._reader.join(timeout=5.0)
        return code

    def stop(self) -> int:
        """SIGINT (escalating) and the exit code."""
        code = stop_process(self.proc)
        if self._reader is not None:
            self._reader.join(timeout=5.0)
        return code


ATTEMPTS = 3
ANSWER_TIMEOUT = 10.0  # [s]


def call_answered(client: Client, request: object) -> object | None:
    """The answer to an idempotent ``request``, sent up to ``ATTEMPTS`` times (each waiting
    ``ANSWER_TIMEOUT``); None if none came. ``wait_for_service`` sees the server's request reader,
    but the server may not yet have matched this client's response reader, and DDS then drops the
    answer (rmw_fastrtps waits at most 100 ms for it: ros2/rmw_fastrtps#390, #467)."""
    for _ in range(ATTEMPTS):
        response = client.call(request, timeout_sec=ANSWER_TIMEOUT)
        if response is not None:
            return response
    return None


class ParameterClient:
    """Set and get single parameters of a running node through its parameter services (arrays come
    back as lists); a request without an answer is sent again (:func:`call_answered`: both requests
    are idempotent)."""

    def __init__(self, node: Node, target: str) -> None:
        self._setter = node.create_client(SetParameters, f"{target}/set_parameters")
        self._getter = node.create_client(GetParameters, f"{target}/get_parameters")
        assert self._setter.wait_for_service(timeout_sec=20.0) and self._getter.wait_for_service(
            timeout_sec=20.0
        )

    def set(self, name: str, value: object) -> SetParametersResult:
        """Request one update; return the node's answer (successful, reason)."""
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()]
        )
        response = call_answered(self._setter, request)
        assert response is not None, f"no answer to setting {name}"
        return response.results[0]

    def get(self, name: str) -> object:
        """The current value of one parameter."""
        response = call_answered(self._getter, GetParameters.Request(names=[name]))
        assert response is not None, f"no answer to getting {name}"
        value = parameter_value_to_python(response.values[0])
        return (
            list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else value
        )


def write_step_sequence(path: Path, steps: int) -> None:
    """A setpoint sequencer parameter file: the paper's first ``steps`` FPU steps; the sequencer
    ends (exit 0) half a second after the last."""
    points = [float(v) for v in step_reference("fpu").p_des[:steps].ravel()]
    parameters = {
        "trajectory": "steps",
        "points": points,
        "exit_on_finish": True,
        "finish_hold": 0.5,
    }
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))


@pytest.fixture(scope="session")
def sim_step_bag(tmp_path_factory) -> Path:
    """The bag of one sim graph run (launch_scripts/sim.launch.yaml, FPU, P-satI-D,
    clock:=lockstep, the default world: calibrated) on the first SIM_STEPS FPU steps of
    SIM_STEP_PERIOD s each, run until the sequencer has played them (exit 0); the modules that
    check such a run (sim in the loop, replay) share it."""
    work = tmp_path_factory.mktemp("sim_steps")
    bag = work / "bag"
    config = work / "sequencer.yaml"
    write_step_sequence(config, SIM_STEPS)
    proc = start_process(
        [
            *LAUNCHER,
            str(SIM_GRAPH),
            *GRAPH_STOP,
            "material:=fpu",
            "controller:=psatid",
            f"setpoint_rate:={1.0 / SIM_STEP_PERIOD}",
            f"bag_dir:={bag}",
            f"sequencer_config:={config}",
            "clock:=lockstep",
        ]
    )
    try:
        output, _ = proc.communicate(timeout=900)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, output[-5000:]
    assert "setpoint_sequencer exited with 0" in output, output[-5000:]
    return bag
