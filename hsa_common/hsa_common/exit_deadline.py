"""A deadline that ends the process with a chosen exit code even while Python is stuck in native
code.

Why: a node's last step, rclpy's ``destroy_node``, can hang inside the middleware (in the final
node-handle destruction of rmw_fastrtps; docs/launch.md, "Teardown bounds"), and that call holds the
GIL, so no Python thread, signal handler or
``Thread.join(timeout)`` can end it. :func:`arm` starts a POSIX timer whose expiry runs libc's
``_exit(code)`` on a thread of its own (``SIGEV_THREAD``), outside the interpreter.

Linux/glibc only (``timer_create``, x86-64 and arm64 calling conventions: the timer's ``sigval`` is
passed as ``_exit``'s int); elsewhere :func:`arm` returns False and the process keeps Python's own
exit path.
"""

from __future__ import annotations

import ctypes
import sys

CLOCK_MONOTONIC = 1
SIGEV_THREAD = 2


class _SigEvent(ctypes.Structure):
    """glibc's struct sigevent (64 bytes) with the SIGEV_THREAD members of its union."""

    _fields_ = [
        ("value", ctypes.c_void_p),
        ("signo", ctypes.c_int),
        ("notify", ctypes.c_int),
        ("function", ctypes.c_void_p),
        ("attribute", ctypes.c_void_p),
        ("pad", ctypes.c_int * 8),
    ]


class _TimeSpec(ctypes.Structure):
    _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [("interval", _TimeSpec), ("value", _TimeSpec)]


def arm(seconds: float, code: int) -> bool:
    """End the process with ``_exit(code)`` once ``seconds`` have passed, whatever Python is doing;
    False where the platform has no such timer (nothing is armed then)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        timer_create, timer_settime, exit_now = libc.timer_create, libc.timer_settime, libc._exit
    except (OSError, AttributeError):
        return False
    event = _SigEvent(
        value=code & 0xFF,
        notify=SIGEV_THREAD,
        function=ctypes.cast(exit_now, ctypes.c_void_p).value,
    )
    timer = ctypes.c_void_p()
    if timer_create(CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
        return False
    whole = int(seconds)
    when = _ITimerSpec(value=_TimeSpec(whole, int((seconds - whole) * 1e9)))
    # the timer lives in the kernel until it fires
    return timer_settime(timer, 0, ctypes.byref(when), None) == 0
