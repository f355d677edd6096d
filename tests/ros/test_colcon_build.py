"""The workspace as a lab builds it: ``colcon build --symlink-install`` (colcon-core and colcon-ros,
pinned in requirements.txt), then every node of every launch graph resolves to the install space's
lib/<pkg>/<exe>, and the sim graph, started from that install with its default parameter files,
brings every node to "ready"."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hsa_common import rosenv
from hsa_common.compose import parse_entries
from hsa_common.launcher import LaunchFile, Process
from tests.ros.conftest import GRAPH_STOP, LAUNCHER, stop_process, wait_until
from tests.ros.test_launch_files import GRAPHS, OPTIONAL_ON, REQUIRED

pytestmark = [pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).parents[2]
PACKAGES = sorted(p.parent for p in REPO.glob("hsa_*/package.xml"))


@pytest.fixture(scope="module")
def install(tmp_path_factory) -> Path:
    """A fresh colcon install space of all packages (hsa_msgs with ament_cmake, the rest
    ament_python), with no CMAKE_BUILD_TYPE as in a lab's plain ``colcon build --symlink-install``.

    colcon's parallel executor (colcon-common-extensions has it) builds independent packages side by
    side, and hsa_msgs' make gets one job per core: colcon's own default adds ``-l <cores>``, under
    which make runs a single job whenever the load average exceeds the core count (the shared test
    machine's normal state)."""
    ws = tmp_path_factory.mktemp("colcon_ws")
    env = {
        **os.environ,
        "AMENT_PREFIX_PATH": sys.prefix,
        "CMAKE_PREFIX_PATH": sys.prefix,
        "MAKEFLAGS": f"-j{len(os.sched_getaffinity(0))}",
    }
    started = time.monotonic()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "colcon",
            "--log-base",
            str(ws / "log"),
            "build",
            "--symlink-install",
            "--executor",
            "parallel",
            "--build-base",
            str(ws / "build"),
            "--install-base",
            str(ws / "install"),
            "--paths",
            *map(str, PACKAGES),
            "--cmake-args",
            f"-DPython3_EXECUTABLE={sys.executable}",
            "-DBUILD_TESTING=OFF",
        ],
        cwd=ws,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, (done.stdout + done.stderr)[-5000:]
    print(f"colcon build of {len(PACKAGES)} packages: {time.monotonic() - started:.0f} s")
    return ws / "install"


def install_environment(install: Path) -> dict[str, str]:
    """What ``source install/setup.bash`` sets for our packages: the install prefixes first, their
    Python and libs."""
    prefixes = [install / p.name for p in PACKAGES]
    site = [
        str(
            p / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
        )
        for p in prefixes
    ]
    env = rosenv.ros_environment(
        {**os.environ, "AMENT_PREFIX_PATH": os.pathsep.join(map(str, prefixes))}
    )
    env["PYTHONPATH"] = os.pathsep.join([*site, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["LD_LIBRARY_PATH"] = os.pathsep.join(
        [str(install / "hsa_msgs" / "lib"), env.get("LD_LIBRARY_PATH", "")]
    )
    return env


def test_every_node_of_every_graph_resolves_to_the_install_space(
    install: Path, monkeypatch
) -> None:
    """ros2 launch would start each of them from install/<pkg>/lib/<pkg>/<exe>: all are there and
    executable."""
    monkeypatch.setenv("AMENT_PREFIX_PATH", install_environment(install)["AMENT_PREFIX_PATH"])
    for graph in GRAPHS:
        for extra in OPTIONAL_ON[graph.name]:
            for proc in LaunchFile(graph, {**REQUIRED.get(graph.name, {}), **extra}).processes():
                exe = Path(proc.cmd[0])
                assert exe.is_relative_to(install) and os.access(exe, os.X_OK), (
                    f"{graph.name}: {proc.name}: {exe}"
                )
                # install/<pkg>/lib/<pkg>/<exe>
                assert exe.parent.name == exe.parent.parent.parent.name, exe


def node_names(proc: Process) -> list[str]:
    """The nodes a launch process runs (several under hsa_compose)."""
    if Path(proc.cmd[0]).name != "hsa_compose":
        return [proc.name]
    return [e.name for e in parse_entries(proc.cmd[1 : proc.cmd.index("--ros-args")])[0]]


def run_graph(
    install: Path,
    graph: str,
    args: dict[str, str],
    cwd: Path,
    ready_text: dict[str, str],
    linger: float = 0.0,
) -> float:
    """Start a graph from the install space; wait until each process logged its ready text; Ctrl-C;
    seconds to ready.

    A graph may end by itself once ready (the replay graph ends when its player is done), within
    ``linger`` [s]; otherwise it is stopped with Ctrl-C then. Either way it must end with 0.
    """
    path = REPO / "launch_scripts" / graph
    procs = LaunchFile(path, args).processes()
    names = [n for p in procs for n in node_names(p)]
    launcher = subprocess.Popen(
        [*LAUNCHER, str(path), *GRAPH_STOP, *(f"{k}:={v}" for k, v in args.items())],
        env=install_environment(install),
        cwd=cwd,
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(launcher.stdout), daemon=True)
    reader.start()
    started = time.monotonic()

    def ready() -> set[str]:
        text = "".join(lines)
        return {
            n
            for n in names
            if re.search(
                rf"\[hsa\.{n}\]: {ready_text.get(n, 'ready')}|^{ready_text.get(n, '@')}", text, re.M
            )
        }

    try:
        assert wait_until(
            lambda: ready() == set(names) or launcher.poll() is not None, timeout=300.0
        )
        assert ready() == set(names), (
            f"not ready: {sorted(set(names) - ready())}\n" + "".join(lines)[-6000:]
        )
        took = time.monotonic() - started
        starts = [line for line in lines if line.startswith("[launch] starting ")]
        assert len(starts) == len(procs) and all(f" {install}/" in line for line in starts), starts
        # a graph that ends by itself may do so
        wait_until(lambda: launcher.poll() is not None, timeout=linger)
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGINT)
        assert launcher.wait(timeout=120.0) == 0, "".join(lines)[-4000:]
    finally:
        stop_process(launcher)
    print(f"{graph} from the colcon install: {len(names)} processes ready after {took:.0f} s")
    return took


@pytest.fixture(scope="module")
def sim_bag(install: Path, tmp_path_factory) -> Path:
    """The sim graph with its defaults from the install space, every node ready; its recording (a
    few seconds): the one date-time bag the default ``bag_dir`` (out/bags/sim/) holds."""
    runs = tmp_path_factory.mktemp("runs")
    run_graph(install, "sim.launch.yaml", {}, runs, {}, linger=5.0)
    bags = sorted((runs / "out" / "bags" / "sim").iterdir())
    assert len(bags) == 1, bags
    return bags[0]


def test_sim_graph_from_the_install_space_brings_every_node_to_ready(sim_bag: Path) -> None:
    """Default sim graph: all 8 nodes (5 processes) from install/<pkg>/lib/<pkg>/<exe> ready,
    stopped with 0, bag written."""
    assert (sim_bag / "metadata.yaml").is_file()


def test_identify_graph_from_the_install_space_brings_every_node_to_ready(
    install: Path, tmp_path: Path
) -> None:
    """Default identification graph (sim:=true): every node ready from the install space."""
    run_graph(install, "identify.launch.yaml", {}, tmp_path, {})


def test_replay_graph_from_the_install_space_plays_a_bag(
    install: Path, sim_bag: Path, tmp_path: Path
) -> None:
    """Replay graph with its defaults: the nodes ready, bag_player (a node entry now) plays and ends
    the graph."""
    run_graph(
        install,
        "replay.launch.yaml",
        {"bag": str(sim_bag)},
        tmp_path,
        {"bag_player": "playing "},
        linger=120.0,
    )
