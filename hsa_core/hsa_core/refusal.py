"""Refused inputs as typed values: the reason (an enum member, for counters) carried with the
one-line text (for logs and /diagnostics).

A :class:`Refusal` is a ``str`` (the text), so whoever shows it needs nothing more; whoever counts
refusals keys by :attr:`Refusal.reason`, never by parsing the text. Each part that refuses inputs
has its own reasons (:class:`StateRejection` here;
:class:`hsa_core.controller.validation.SetpointRejection`,
:class:`hsa_core.sensing.mocap_gate.Rejection`); their values are the names shown on /diagnostics.
"""

from __future__ import annotations

import enum


class Refusal(str):
    """The text of a refusal (``str``) with its ``reason``."""

    reason: enum.Enum

    def __new__(cls, reason: enum.Enum, text: str) -> Refusal:
        """A refusal for ``reason`` shown as ``text`` (one line)."""
        refusal = super().__new__(cls, text)
        refusal.reason = reason
        return refusal

    @classmethod
    def of(cls, reason: enum.StrEnum, detail: str = "") -> Refusal:
        """The usual form: ``"<reason>: <detail>"``, or the reason alone without a detail."""
        return cls(reason, f"{reason}: {detail}" if detail else str(reason))


class StateRejection(enum.StrEnum):
    """Why the controller refuses a measured state: implausible values
    (hsa_core.controller.validation.state_problem) or its stamp's order (Supervisor.state)."""

    NON_FINITE_POSE = "non-finite pose or configuration"
    IMPLAUSIBLE_POSE = "implausible pose or configuration"
    NON_FINITE_RATES = "non-finite rates"
    IMPLAUSIBLE_RATES = "implausible rates"
    OLDER = "older than the newest state"
    FUTURE = "stamped in the future"
