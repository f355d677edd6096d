"""A node ends when the process that started it ends: Linux's parent-death signal
(``prctl(PR_SET_PDEATHSIG)``).

Why: a launcher killed with SIGKILL (or by the OOM killer) cannot stop its children, and a node
without a parent keeps driving the robot. The kernel sends the chosen signal to the node when its
parent ends, whoever the parent is (``hsa_launch``, ``ros2 launch``, ``ros2 run``, a shell); the
runner treats it like SIGINT (torque off first).

Rules (:func:`tie_to_parent`):

* a process started by ``hsa_launch`` finds the launcher's PID in ``HSA_PARENT_PID``; after arming
  the signal it checks that the launcher is still alive, which closes the race of a launcher that
  ended before the node got this far (Python start-up, about a second): such a node is
  :attr:`Tie.ORPHANED` and must not start;
* any other parent (``ros2 launch``, ``ros2 run``, a shell) gets the same signal but no such check:
  a parent that ends within the node's first second leaves it running (``ros2 launch`` passes no PID
  to check against);
* a process that started with SIGHUP ignored and no ``HSA_PARENT_PID`` (``nohup node &``) was
  detached on purpose: it is :attr:`Tie.DETACHED` and outlives its shell. A node started by hand
  otherwise stops when its shell ends.

The signal is tied to the parent *thread*: the launcher starts its children from its main thread,
which lives as long as the launcher. It survives ``execve`` and is cleared by ``fork``, so it
concerns this process only.
"""

from __future__ import annotations

import ctypes
import enum
import os
import select
import signal
import sys
from collections.abc import Callable

PARENT_ENV = "HSA_PARENT_PID"
"""Environment variable in which a launcher passes its PID to the processes it starts."""
_PR_SET_PDEATHSIG = 1
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
"""Signals that stop a node or a graph like Ctrl-C (torque off first): a closed terminal or ssh
session and Ctrl-\\ too."""


class Tie(enum.Enum):
    """What :func:`tie_to_parent` did."""

    TIED = "the parent's end sends the signal"
    ORPHANED = "the launcher named by HSA_PARENT_PID has already ended"
    DETACHED = "started with SIGHUP ignored (nohup) and no launcher: not tied"
    UNSUPPORTED = "no prctl on this platform: not tied"


def tie_to_parent(signum: int = signal.SIGTERM) -> Tie:
    """Ask the kernel to send ``signum`` to this process when its parent ends (rules in the module
    docstring).

    Call it before installing a handler for SIGHUP: a SIGHUP ignored at start is what marks a
    detached process.
    """
    launcher = os.environ.get(PARENT_ENV)
    if launcher is None and signal.getsignal(signal.SIGHUP) == signal.SIG_IGN:
        return Tie.DETACHED
    if not sys.platform.startswith("linux"):
        return Tie.UNSUPPORTED
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return Tie.UNSUPPORTED
    if prctl(_PR_SET_PDEATHSIG, int(signum), 0, 0, 0) != 0:
        return Tie.UNSUPPORTED
    if launcher is not None and not alive(int(launcher)):
        return Tie.ORPHANED
    return Tie.TIED


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists and has not ended (a zombie, ended but not yet reaped, counts
    as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as file:
            stat = file.read()
    except OSError:
        return False
    return stat.rsplit(")", 1)[-1].split()[0] not in (
        "Z",
        "X",  # the state follows the command name's ')'
    )


def on_stop_signals(handler: Callable[[int, object], None]) -> None:
    """Install ``handler`` for :data:`STOP_SIGNALS`; a SIGHUP ignored at start (``nohup``) stays
    ignored. Call it after :func:`tie_to_parent`, which reads that disposition. The handler must
    take no lock (:class:`StopFlag`): Python runs a handler on the main thread between two
    instructions, also inside a handler that is already running, and then waits forever for a lock
    that thread holds itself."""
    for sig in STOP_SIGNALS:
        if sig != signal.SIGHUP or signal.getsignal(sig) != signal.SIG_IGN:
            signal.signal(sig, handler)


class StopFlag:
    """The stop signals received so far, set from a signal handler without a lock and waited for
    from any thread. ``threading.Event.set`` takes a lock: a second signal that lands while the
    first handler holds it deadlocks the main thread (a Ctrl-C to a graph's process group delivers
    two). ``set`` appends to a list and writes a byte to a pipe that is never read, so every
    ``wait`` returns at once from then on."""

    def __init__(self) -> None:
        self.signals: list[int] = []
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)

    def set(self, signum: int = 0) -> None:
        """Record ``signum`` (safe in a signal handler, also re-entered)."""
        self.signals.append(signum)
        try:
            os.write(self._write, b"\0")
        except BlockingIOError:  # the pipe is full: it is readable already
            pass

    def is_set(self) -> bool:
        """Whether a stop signal has arrived."""
        return bool(self.signals)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until a stop signal has arrived or ``timeout`` [s] has passed; whether one has."""
        if not self.signals:
            select.select([self._read], [], [], timeout)
        return bool(self.signals)
