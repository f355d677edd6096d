"""Errors the middleware sets and leaves behind: cleared after every executor step and reported in
one throttled line.

rcutils keeps one error state per thread. rmw_fastrtps sets it when an incoming message fails to
deserialize ("Fast CDR exception deserializing message of type ...") and still returns success with
nothing taken, so rclpy drops the message without a callback and never clears the state. The next
error with a different text (e.g. a malformed message of another type) then makes rcutils print an
11-line "This error state is being overwritten" block to stderr; the print is compiled in
(``RCUTILS_REPORT_ERROR_HANDLING_ERRORS``), no setting turns it off. The runner calls
:meth:`MiddlewareErrors.check` after every executor step, on the thread that spins (where the take
ran): it reads and resets the state, counts it, and logs it at WARN at most every ``period``
seconds.
"""

from __future__ import annotations

import ctypes
import os
import time

from rclpy.node import Node

# RCUTILS_ERROR_MESSAGE_MAX_LENGTH: rcutils_error_string_t is a char[1024]
ERROR_STRING_LENGTH = 1024
LOG_PERIOD = 5.0  # [s] steady time between two WARN lines


class _ErrorString(ctypes.Structure):
    """rcutils_error_string_t, returned by value."""

    _fields_ = [("text", ctypes.c_char * ERROR_STRING_LENGTH)]


def _rcutils() -> ctypes.CDLL:
    """The librcutils that rclpy has loaded (never a second copy: its error state would be another
    one)."""
    lib = ctypes.CDLL("librcutils.so", mode=os.RTLD_NOLOAD | ctypes.RTLD_GLOBAL)
    lib.rcutils_error_is_set.restype = ctypes.c_bool
    lib.rcutils_error_is_set.argtypes = []
    lib.rcutils_get_error_string.restype = _ErrorString
    lib.rcutils_get_error_string.argtypes = []
    lib.rcutils_reset_error.restype = None
    lib.rcutils_reset_error.argtypes = []
    return lib


class MiddlewareErrors:
    """Clears and reports the calling thread's leftover rcutils error state (see the module
    docstring)."""

    def __init__(self, node: Node, period: float = LOG_PERIOD) -> None:
        self._lib = _rcutils()
        self._node = node
        self._period = period
        self._logged = -period  # steady time [s] of the last line
        self.count = 0  # errors cleared so far

    def check(self) -> None:
        """Clear the error state if set; log it (throttled) with the running count."""
        if not self._lib.rcutils_error_is_set():
            return
        text = self._lib.rcutils_get_error_string().text.decode("utf8", errors="replace")
        self._lib.rcutils_reset_error()
        self.count += 1
        now = time.monotonic()
        if now - self._logged >= self._period:
            self._logged = now
            self._node.get_logger().warning(
                "middleware error (an incoming message that fails to deserialize is dropped): "
                f"{text} [{self.count} so far; at most one line per {self._period:g} s]"
            )
