"""Declarative node parameters: each one declared with a description and range, validated at start
and at run time.

A node lists its parameters as :class:`ParamSpec` entries. :func:`declare` declares them (so ``ros2
param describe`` shows units, ranges and whether they are read-only), validates the start values and
raises :class:`ParameterValidationError` naming the first bad parameter; a value given for a
parameter the node does not have (a typo in a parameter file or on the command line, which rclpy
would silently ignore) is refused the same way. An integer given for a floating-point parameter
(``rate:=2``) is taken as the float it spells. :func:`guard_updates` installs the on-set callback
that refuses out-of-range or read-only updates at run time with a reason naming the parameter; the
node keeps running with the old value. The callback has no side effects: accepted values are applied
by the post-set callback the node passes in. :func:`typed` builds the frozen dataclass that ROS-free
code takes from the values (no dict of parameters crosses into hsa_core).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

QOS_OVERRIDES = "qos_overrides."
"""Prefix of the standard QoS override parameters, declared when the publisher or subscription is
created."""

# returns an error message, or None if the value is acceptable
Validator = Callable[[Any], str | None]
T = TypeVar("T")


class ParameterValidationError(ValueError):
    """A node parameter has a value the node refuses; the message names the parameter."""


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: name, default, description with units, optional range/choices/length and
    validator."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[str] | None = None
    length: int | None = None  # required length of an array parameter
    read_only: bool = False
    validator: Validator | None = field(default=None, compare=False)

    def descriptor(self) -> ParameterDescriptor:
        """The rcl descriptor (ranges only for scalars; rclpy then enforces them too)."""
        desc = ParameterDescriptor(description=self.description, read_only=self.read_only)
        extra = []
        if self.choices:
            extra.append(f"one of {list(self.choices)}")
        if self.length is not None:
            extra.append(f"length {self.length}")
        if self.low is not None or self.high is not None:
            extra.append(f"range [{self.low}, {self.high}]")
        desc.additional_constraints = "; ".join(extra)
        is_scalar = isinstance(self.default, (int, float)) and not isinstance(self.default, bool)
        if is_scalar and self.low is not None and self.high is not None:
            if isinstance(self.default, float):
                desc.floating_point_range = [
                    FloatingPointRange(from_value=float(self.low), to_value=float(self.high))
                ]
            else:
                desc.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=1)
                ]
        return desc

    def check(self, value: Any) -> str | None:
        """Return why ``value`` is unacceptable for this parameter, or None."""
        values = (
            list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else None
        )
        if self.length is not None and (values is None or len(values) != self.length):
            return f"must be a list of length {self.length}, got {value!r}"
        for v in values if values is not None else [value]:
            if isinstance(v, float) and not math.isfinite(v):
                return f"must be finite, got {value!r}"
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                if self.low is not None and v < self.low or self.high is not None and v > self.high:
                    return f"must be within [{self.low}, {self.high}], got {value!r}"
        if self.choices is not None and value not in self.choices:
            return f"must be one of {list(self.choices)}, got {value!r}"
        return self.validator(value) if self.validator else None


def declare(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare and validate all parameters; return their values by name (raises
    ParameterValidationError)."""
    values: dict[str, Any] = {}
    for spec in specs:
        _accept_integer_spelling(node, spec)
        try:
            param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except (
            Exception
        ) as exc:  # rclpy range/type rejection of an override: re-raise naming the parameter
            raise ParameterValidationError(f"parameter '{spec.name}': {exc}") from exc
        value = param.value
        problem = spec.check(value)
        if problem:
            raise ParameterValidationError(f"parameter '{spec.name}' {problem}")
        values[spec.name] = (
            list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else value
        )
    unknown = unknown_overrides(node)
    if unknown:
        raise ParameterValidationError(
            f"parameter '{unknown[0]}' is not a parameter of {node.get_name()} (misspelt, or meant "
            f"for another node?); known: {sorted(s.name for s in specs)}"
        )
    return values


def typed(cls: type[T], values: Mapping[str, Any], **names: str) -> T:
    """The dataclass ``cls`` from parameter values: each field takes the parameter of its name, or
    the one ``names`` gives it; the class's own check (a ValueError) becomes a
    ParameterValidationError naming those parameters."""
    fields = {f.name: names.get(f.name, f.name) for f in dataclasses.fields(cls) if f.init}
    try:
        return cls(**{name: values[parameter] for name, parameter in fields.items()})
    except ValueError as exc:
        raise ParameterValidationError(f"parameters {sorted(fields.values())}: {exc}") from exc


def _accept_integer_spelling(node: Node, spec: ParamSpec) -> None:
    """Turn an integer override of a floating-point parameter (``rate:=2``, ``[1, 2]``) into the
    float it means.

    rcl types ``2`` as INTEGER, and rclpy refuses it for a DOUBLE parameter ("expecting type
    'DOUBLE'"); launch arguments and parameter files are written by people, so ``2`` must mean
    ``2.0``, under ros2 launch as well.
    """
    # the resolved overrides (see unknown_overrides)
    given = node._parameter_overrides.get(spec.name)
    if given is None:
        return
    default = spec.default
    floats = (
        isinstance(default, list) and bool(default) and all(isinstance(v, float) for v in default)
    )
    if given.type_ == Parameter.Type.INTEGER and (
        isinstance(default, float) or default == Parameter.Type.DOUBLE
    ):
        node._parameter_overrides[spec.name] = Parameter(
            spec.name, Parameter.Type.DOUBLE, float(given.value)
        )
    elif given.type_ == Parameter.Type.INTEGER_ARRAY and (
        floats or default == Parameter.Type.DOUBLE_ARRAY
    ):
        node._parameter_overrides[spec.name] = Parameter(
            spec.name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in given.value]
        )


RUNNER_PARAMS = frozenset({"lockstep"})
"""Parameters every node accepts, declared by the runner (hsa_common.runner): ``lockstep``."""


def unknown_overrides(node: Node) -> list[str]:
    """Names given to the node (parameter files, ``-p``) that it has not declared; QoS overrides are
    declared later."""
    # rclpy keeps the node's resolved overrides only here (no public accessor)
    given = node._parameter_overrides
    return sorted(
        name
        for name in given
        if not node.has_parameter(name)
        and not name.startswith(QOS_OVERRIDES)
        and name not in RUNNER_PARAMS
    )


def guard_updates(
    node: Node, specs: Sequence[ParamSpec], apply: Callable[[dict[str, Any]], None] | None = None
) -> None:
    """Refuse invalid run-time updates with a reason; hand accepted ones to ``apply`` after they are
    set."""
    by_name = {s.name: s for s in specs}

    def on_set(params: list[Parameter]) -> SetParametersResult:
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue  # e.g. use_sim_time, qos_overrides: rclpy validates those
            if spec.read_only:
                return SetParametersResult(
                    successful=False, reason=f"parameter '{p.name}' is read-only"
                )
            problem = spec.check(p.value)
            if problem:
                node.get_logger().warning(f"refused update of '{p.name}': {problem}")
                return SetParametersResult(
                    successful=False, reason=f"parameter '{p.name}' {problem}"
                )
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    if apply is not None:

        def post_set(params: list[Parameter]) -> None:
            apply({p.name: p.value for p in params if p.name in by_name})

        node.add_post_set_parameters_callback(post_set)
