"""hsa_common.parent_death and hsa_common.fastdds_shm without ROS (issue 22, items 4 and 8): which
processes are tied to their parent, that the parent's death delivers SIGTERM, and that the /dev/shm
clean-up removes only files no live process uses (plain processes holding flocks and mappings as
Fast DDS does, on files in a temporary directory)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from hsa_common import fastdds_shm, parent_death
from tests.ros.conftest import start_process, wait_for_line, wait_until

TIE = "from hsa_common import parent_death; print(parent_death.tie_to_parent().name, flush=True)"


def tie(env: dict[str, str], prelude: str = "") -> str:
    """What tie_to_parent answers in a fresh process with ``env`` (after running ``prelude``)."""
    return subprocess.run(
        [sys.executable, "-c", prelude + TIE], env=env, capture_output=True, text=True, check=True
    ).stdout.strip()


def test_tie_to_parent_answers_by_launcher_and_nohup() -> None:
    env = {k: v for k, v in os.environ.items() if k != parent_death.PARENT_ENV}
    ended = subprocess.Popen(["true"])
    ended.wait()
    # the launcher ended before the node
    assert tie({**env, parent_death.PARENT_ENV: str(ended.pid)}) == "ORPHANED"
    assert tie({**env, parent_death.PARENT_ENV: str(os.getpid())}) == "TIED"
    assert tie(env) == "TIED"  # ros2 launch, ros2 run, a shell
    # nohup
    assert tie(env, "import signal; signal.signal(signal.SIGHUP, signal.SIG_IGN); ") == "DETACHED"


def test_a_tied_process_gets_sigterm_when_its_parent_is_killed(tmp_path) -> None:
    marker = tmp_path / "got_sigterm"
    child = (
        "import signal, sys, time; from hsa_common import parent_death; "
        f"signal.signal(signal.SIGTERM, lambda *_: (open({str(marker)!r}, 'w').close(), "
        "sys.exit(0))); assert parent_death.tie_to_parent() is parent_death.Tie.TIED; "
        "print('tied', flush=True); time.sleep(60)"
    )
    middle = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import subprocess, sys; p = subprocess.Popen([sys.executable, "
            f"'-c', {child!r}]); print(p.pid, flush=True); p.wait()",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    grandchild = int(middle.stdout.readline())
    try:
        assert middle.stdout.readline().strip() == "tied"  # the grandchild writes to the same pipe
        middle.kill()
        middle.wait()
        assert wait_until(marker.exists, 10.0), "no SIGTERM after the parent's SIGKILL"
        assert wait_until(lambda: not parent_death.alive(grandchild), 10.0)
    finally:
        if parent_death.alive(grandchild):
            os.kill(grandchild, signal.SIGKILL)


HOLDER = """
import fcntl, mmap, os, sys
d = sys.argv[1]
live = os.open(f"{d}/fastrtps_fedcba9876543210_el", os.O_RDONLY)
fcntl.flock(live, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a live participant holds its lock
# a peer of a dead owner; a writer to a port
maps = [mmap.mmap(os.open(f"{d}/{name}", os.O_RDWR), 4096) for name in
        ("fastrtps_1111111111111111", "fastrtps_port99998")]
opening = os.open(f"{d}/fastrtps_3333333333333333_el", os.O_RDONLY)  # created, not locked yet
print("ready", flush=True)
sys.stdin.read()
"""


def test_remove_unused_removes_only_what_no_live_process_uses(tmp_path) -> None:
    directory = tmp_path.resolve()
    groups = {
        "dead participant": ["fastrtps_0123456789abcdef", "fastrtps_0123456789abcdef_el"],
        "live participant": ["fastrtps_fedcba9876543210", "fastrtps_fedcba9876543210_el"],
        "dead participant, still mapped by a peer": [
            "fastrtps_1111111111111111",
            "fastrtps_1111111111111111_el",
        ],
        "port without reader, a writer maps it": ["fastrtps_port99998"],
        "port nobody uses": ["fastrtps_port99999", "fastrtps_port99999_el"],
        "lock file created, not yet locked": [
            "fastrtps_3333333333333333",
            "fastrtps_3333333333333333_el",
        ],
        "not Fast DDS": ["other_file"],
    }
    for names in groups.values():
        for name in names:
            (directory / name).write_bytes(b"\0" * (0 if name.endswith("_el") else 4096))
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(directory)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "ready"
        time.sleep(0.6)
        young = [
            "fastrtps_2222222222222222",
            "fastrtps_2222222222222222_el",  # unlocked but just created
        ]
        for name in young:
            (directory / name).touch()
        removed = set(fastdds_shm.remove_unused(grace=0.5, directory=directory))
        assert fastdds_shm.owned_by(holder.pid, directory) == {
            "fastrtps_fedcba9876543210",
            "fastrtps_3333333333333333",
        }
    finally:
        holder.communicate("")
    gone = {
        *groups["dead participant"],
        *groups["dead participant, still mapped by a peer"],
        *groups["port nobody uses"],
    }
    assert removed == gone
    assert {p.name for p in directory.iterdir()} == {
        n for names in groups.values() for n in names
    } - gone | {*young}


def test_the_teardown_priority_reaches_every_thread() -> None:
    # os.nice would change the calling thread's only (Linux: a thread's nice value is its own)
    child = (
        "import os, threading; from hsa_common import runner; "
        "started, done = threading.Event(), threading.Event(); "
        "t = threading.Thread(target=lambda: (started.set(), done.wait())); t.start(); "
        "started.wait(); runner.lower_priority(3); "
        "later = threading.Thread(target=lambda: print(os.getpriority(os.PRIO_PROCESS, 0))); "
        "later.start(); later.join(); "
        "print(os.getpriority(os.PRIO_PROCESS, 0), os.getpriority(os.PRIO_PROCESS, t.native_id)); "
        "done.set()"
    )
    before = os.getpriority(os.PRIO_PROCESS, 0)
    out = subprocess.run(
        [sys.executable, "-c", child], capture_output=True, text=True, check=True
    ).stdout.split()
    assert [int(v) for v in out] == [min(before + 3, 19)] * 3, out


FLOOD = """
import os, signal, sys, threading
from hsa_common import parent_death
flag = parent_death.StopFlag()
signal.signal(signal.SIGUSR2, lambda signum, _frame: flag.set(signum))
def flood():
    for _ in range(20000):
        signal.pthread_kill(threading.main_thread().ident, signal.SIGUSR2)
flooder = threading.Thread(target=flood)
flooder.start()
while flooder.is_alive():
    flag.set(0)  # the handler runs inside this call, again and again
flooder.join()
print(flag.wait(0.0), 0 in flag.signals, signal.SIGUSR2 in flag.signals)
"""


def test_a_stop_flag_set_by_a_handler_that_interrupts_its_own_set_never_blocks() -> None:
    # threading.Event.set takes a lock there and waited forever for it (a Ctrl-C to a graph's
    # process group once deadlocked sim_node's stop handler that way)
    out = subprocess.run([sys.executable, "-c", FLOOD], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split() == ["True"] * 3, out.stderr


def test_a_burst_of_stop_signals_ends_a_node_with_0() -> None:
    """Stop signals arriving while the node's stop handler runs (the process group's SIGINT, the
    launcher's, the stop watch's) must not leave it running."""
    node = start_process(
        [
            sys.executable,
            "-c",
            "from rclpy.node import Node; from hsa_common.runner import run; "
            "run(lambda: Node('signal_burst'), 'signal_burst')",
        ]
    )
    try:
        wait_for_line(node, "ready", timeout=120.0)
        for _ in range(3000):
            if node.poll() is not None:
                break
            os.kill(node.pid, signal.SIGINT)
        output, _ = node.communicate(timeout=60)
    finally:
        if node.poll() is None:
            node.kill()
    assert node.returncode == 0, output
