"""A graph ends safely however its launcher ends (issue 22, items 3, 4 and 8): a closed terminal
(SIGHUP to the launcher as the terminal's session leader, or to the whole process group as a shell
forwards it) and a SIGKILL of the launcher alone both turn torque off and end every process; a clean
end leaves none of the graph's Fast DDS files in /dev/shm, and after a SIGKILLed graph the
launcher's clean-up removes its files but none of a live graph's.

Each graph is hsa_launch with one dynamixel_driver on its own MX-28 emulator (in this process, whose
write log shows torque), in a session of its own with a pseudo-terminal as its controlling terminal;
the four start in parallel."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hsa_common import fastdds_shm, rosenv
from hsa_common.parent_death import alive
from tests.ros.driver_harness import (
    IDS,
    NEUTRAL,
    make_emulator,
    torque,
    torque_off_time,
    wait_until,
)
from tests.ros.faults import fault

pytestmark = pytest.mark.ros

CTTY = (
    "import fcntl, os, sys, termios; fcntl.ioctl(0, termios.TIOCSCTTY, 0); "
    "os.execv(sys.executable, [sys.executable, '-m', 'hsa_common.launcher', *sys.argv[1:]])"
)
"""Makes the new session's pseudo-terminal (stdin) its controlling terminal, then becomes hsa_launch
(same PID)."""


class Graph:
    """hsa_launch with one driver named ``name``, as the session leader of a pseudo-terminal whose
    output is drained."""

    def __init__(self, tmp_path: Path, name: str) -> None:
        self.name = name
        self.emulator = make_emulator(tmp_path, f"tty_{name}")
        graph = tmp_path / f"{name}.launch.yaml"
        graph.write_text(
            f"launch:\n- node: {{pkg: hsa_dynamixel_driver, exec: dynamixel_driver, name: {name}, "
            f"param: [{{name: port, value: '{self.emulator.port}'}}, "
            f"{{name: neutral_ticks, value: {[NEUTRAL[i] for i in IDS]}}}]}}\n"
        )
        self.master, terminal = os.openpty()
        self.launcher = subprocess.Popen(
            [sys.executable, "-c", CTTY, str(graph)],
            env=rosenv.ros_environment(),
            start_new_session=True,
            stdin=terminal,
            stdout=terminal,
            stderr=terminal,
        )
        os.close(terminal)
        self.output = bytearray()
        self._open = True
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()
        self.pids: list[int] = []
        self.files: set[str] = set()

    def _drain(self) -> None:
        while self._open:
            if select.select([self.master], [], [], 0.1)[0]:
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    return
                if not data:
                    return
                self.output += data

    def record(self) -> None:
        """The launcher's and its children's PIDs, and the Fast DDS files they own (the groups whose
        lock they hold: the ports of other participants that they only write to are those
        participants')."""
        children = (
            Path(f"/proc/{self.launcher.pid}/task/{self.launcher.pid}/children").read_text().split()
        )
        self.pids = [self.launcher.pid, *map(int, children)]
        assert len(self.pids) == 2, self.text()
        owned = set().union(*(fastdds_shm.owned_by(pid) for pid in self.pids))
        self.files = {
            name for name in os.listdir(fastdds_shm.SHM_DIR) if fastdds_shm.group_of(name) in owned
        }
        assert self.files, "the driver owns no Fast DDS shared-memory file"

    def stop_reading(self) -> None:
        """Stop draining the terminal (before it is closed)."""
        self._open = False
        self._reader.join(timeout=2.0)

    def hang_up(self) -> None:
        """Close the terminal: the kernel sends SIGHUP to its session leader, the launcher."""
        os.close(self.master)
        self.master = -1

    def ended(self) -> bool:
        """Every process of the graph has ended (the launcher is reaped here; a reparented child
        counts when dead)."""
        self.launcher.poll()
        return not any(alive(pid) for pid in self.pids)

    def present(self) -> set[str]:
        """The graph's Fast DDS files still in /dev/shm."""
        return {name for name in self.files if (fastdds_shm.SHM_DIR / name).exists()}

    def left(self) -> set[str]:
        """The graph's Fast DDS files still in /dev/shm whose group no live process uses (a port
        number that another participant took over since, or writes to, is that participant's)."""
        present = self.present()
        used = {fastdds_shm.group_of(name) for name in fastdds_shm.in_use()} if present else set()
        return {name for name in present if fastdds_shm.group_of(name) not in used}

    def unreleased(self) -> set[str]:
        """The graph's participant segments and lock files still in /dev/shm, but for ports another
        participant owns by now: what its participants remove when they are destroyed. (A port's
        segment stays while a peer writes to it; the launcher removes it once unused.)"""
        present = {
            name for name in self.present() if "_port" not in name or name.endswith(("_el", "_sl"))
        }
        owned = fastdds_shm.owned() if present else set()
        return {name for name in present if fastdds_shm.group_of(name) not in owned}

    def text(self) -> str:
        return self.output.decode(errors="replace")[-3000:]

    def close(self) -> None:
        for pid in self.pids if self.pids else [self.launcher.pid]:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        self.launcher.wait(timeout=10.0)
        self.stop_reading()
        if self.master >= 0:
            self.hang_up()
        self.emulator.stop()


def test_hangup_and_a_killed_launcher_turn_torque_off_and_end_the_graph_and_its_shm_files(
    tmp_path,
) -> None:
    cases = ("hangup", "group_sighup", "launcher_sigkill", "graph_sigkill")
    graphs = {case: Graph(tmp_path, f"driver_{case}") for case in cases}
    figures = {}
    try:
        for graph in graphs.values():
            assert wait_until(lambda g=graph: torque(g.emulator) == {True}, 240.0), graph.text()
            graph.record()
        # a SIGKILLed graph leaves its files; the clean-up removes them, and no file of the three
        # live graphs
        killed = graphs["graph_sigkill"]
        os.killpg(killed.launcher.pid, signal.SIGKILL)
        assert wait_until(killed.ended, 10.0)
        assert killed.present(), "a SIGKILLed graph left no Fast DDS file (nothing to clean)"
        newest = max(os.stat(fastdds_shm.SHM_DIR / name).st_mtime for name in killed.present())
        time.sleep(max(0.0, newest + fastdds_shm.GRACE + 0.5 - time.time()))
        removed = fastdds_shm.remove_unused()
        assert not killed.left(), f"left after the clean-up: {killed.left()}"
        live = {name for case in cases[:3] for name in graphs[case].files}
        assert not live.intersection(removed), (
            f"removed files of live graphs: {live.intersection(removed)}"
        )
        figures["graph_sigkill"] = (
            f"{len(removed)} unused files removed, none of the three live graphs'"
        )
        for case in cases[:3]:
            graph = graphs[case]
            graph.stop_reading()
            sent = time.monotonic()
            if case == "launcher_sigkill":
                graph.launcher.kill()
            else:
                graph.hang_up()
                if case == "group_sighup":
                    # as the shell forwards its SIGHUP to its jobs
                    os.killpg(graph.launcher.pid, signal.SIGHUP)
            assert wait_until(graph.ended, 30.0), (
                f"{case}: still running {[p for p in graph.pids if alive(p)]}"
            )
            gone = time.monotonic() - sent
            off = torque_off_time(graph.emulator, sent)
            assert off is not None and torque(graph.emulator) == {False}, (
                f"{case}: torque stayed on\n{graph.text()}"
            )
            assert not graph.unreleased(), (
                f"{case}: Fast DDS files left in /dev/shm: {graph.unreleased()}"
            )
            if (
                case != "launcher_sigkill"
            ):  # it reported to a closed terminal and still stopped the graph cleanly
                assert graph.launcher.returncode == 0, (
                    f"{case}: launcher exit {graph.launcher.returncode}"
                )
            figures[case] = (
                f"torque off {(off - sent) * 1e3:.1f} ms, every process gone {gone:.2f} s after it"
            )
    finally:
        for graph in graphs.values():
            graph.close()
    what = {
        "hangup": "terminal closed (SIGHUP to hsa_launch as session leader)",
        "group_sighup": (
            "terminal closed and SIGHUP to the graph's process group (as a shell forwards it)"
        ),
        "launcher_sigkill": (
            "SIGKILL to hsa_launch alone (the driver gets SIGTERM as its parent dies)"
        ),
        "graph_sigkill": "SIGKILL to the whole graph, then the launcher's /dev/shm clean-up",
    }
    for case, figure in figures.items():
        fault(what[case], figure, "restart")
