"""hsa_common.exit_deadline and the runner's bounded teardown: a process stuck in native code that
holds the GIL still ends, with the exit code it was meant to have."""

from __future__ import annotations

import ctypes
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.ros.conftest import PEERS, start_process, wait_for_line

pytestmark = pytest.mark.ros

STUCK = """
import ctypes, sys
from hsa_common import exit_deadline
assert exit_deadline.arm(0.5, int(sys.argv[1]))
if sys.argv[2] == "stuck":
    ctypes.PyDLL(None).sleep(60)  # a C call that keeps the GIL: no Python runs until it returns
sys.exit(3)
"""


@pytest.mark.parametrize("code", [0, 7])
def test_the_deadline_ends_a_process_stuck_with_the_gil(code: int) -> None:
    out = subprocess.run(
        [sys.executable, "-c", STUCK, str(code), "stuck"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == code, out.stderr


def test_a_process_that_ends_before_the_deadline_keeps_its_own_exit() -> None:
    out = subprocess.run(
        [sys.executable, "-c", STUCK, "7", "free"], capture_output=True, text=True, timeout=30
    )
    assert out.returncode == 3, out.stderr


def test_a_node_stuck_in_destroy_node_ends_with_its_code_and_its_stack() -> None:
    """The runner bounds rclpy's teardown (TEARDOWN_LIMIT): the node leaves with exit_code 5, not a
    SIGKILL, and its output names where it hung."""
    proc = start_process([sys.executable, str(PEERS / "stuck_teardown.py"), "5"])
    try:
        wait_for_line(proc, "ready")
        proc.send_signal(signal.SIGINT)
        # the runner's limit is 6 s; the stuck call alone lasts 60 s
        output, _ = proc.communicate(timeout=40)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 5, output
    assert "Timeout (0:00:05)!" in output and "in destroy_node" in output, output


def _unblocked_thread(pid: int, sig: signal.Signals) -> int:
    """A thread of ``pid`` other than its main thread that does not block ``sig``."""
    for tid in sorted(int(t) for t in os.listdir(f"/proc/{pid}/task")):
        status = Path(f"/proc/{pid}/task/{tid}/status").read_text()
        blocked = int(
            next(ln for ln in status.splitlines() if ln.startswith("SigBlk:")).split()[1], 16
        )
        if tid != pid and not blocked & (1 << (sig - 1)):
            return tid
    raise AssertionError(f"every thread of {pid} but the main one blocks {sig.name}")


@pytest.mark.parametrize(
    ("sig", "to_thread"),
    [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGTERM, True)],
    ids=["SIGINT", "SIGTERM", "SIGTERM-to-another-thread"],
)
def test_a_stop_during_construction_ends_the_node_at_once(
    sig: signal.Signals, to_thread: bool
) -> None:
    """A stop signal while the node is still being created ends it with exit 0, without waiting for
    the construction (a simulator compiling its world once needed the launcher's SIGTERM
    escalation). Also when it reaches another thread: the kernel may hand a process's signal to any
    thread that does not block it (seen in the suite on a loaded machine), and Python runs the
    handler only when the main thread next runs Python, which a main thread asleep in a system call
    would not."""
    proc = start_process([sys.executable, str(PEERS / "slow_start.py")])
    try:
        wait_for_line(proc, "constructing")
        if to_thread:
            tid = _unblocked_thread(proc.pid, sig)
            assert ctypes.CDLL(None, use_errno=True).tgkill(proc.pid, tid, sig) == 0
        else:
            proc.send_signal(sig)
        output, _ = proc.communicate(timeout=40)  # the construction alone lasts 60 s
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, output
    assert "stopped before ready" in output and "ready\n" not in output.replace(
        "before ready", ""
    ), output


def test_a_refused_node_ends_with_2_without_the_interpreters_teardown() -> None:
    """A refusal at start leaves like a stop (bounded rclpy teardown, then os._exit), whatever the
    interpreter's teardown would do."""
    proc = start_process([sys.executable, str(PEERS / "refused_stuck_exit.py")])
    try:
        output, _ = proc.communicate(timeout=40)  # the hanging exit handler alone lasts 60 s
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, output
    assert "refusing to start: parameter 'max_iteration'" in output, output


def test_the_launcher_says_where_a_node_that_ignores_its_stop_is_stuck(tmp_path) -> None:
    """A node stuck in native code with the GIL ignores SIGINT and SIGTERM; before SIGKILL the
    launcher prints its threads as the kernel sees them and its Python stacks, and exits 137."""
    graph = tmp_path / "stuck.launch.yaml"
    graph.write_text(
        f"launch:\n- executable: {{cmd: '{sys.executable} {PEERS / 'stuck_spin.py'}', "
        "name: stuck_spin, output: screen}\n"
    )
    launcher = start_process(
        [
            sys.executable,
            "-m",
            "hsa_common.launcher",
            "--sigterm-timeout",
            "1",
            "--sigkill-timeout",
            "1",
            str(graph),
        ]
    )
    try:
        wait_for_line(launcher, "stuck now", timeout=60.0)
        launcher.send_signal(signal.SIGINT)
        output, _ = launcher.communicate(timeout=30.0)
    finally:
        if launcher.poll() is None:
            launcher.kill()
    assert launcher.returncode == 128 + signal.SIGKILL, output
    assert "stuck_spin (PID" in output and "did not stop on SIGINT or SIGTERM" in output, output
    assert re.search(r"\[launch\]   thread \d+ 'python[^']*' state S wchan \S+", output), output
    assert "in hang_in_native_code" in output and "stuck_spin exited with -9" in output, output
