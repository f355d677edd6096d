"""The common model parameters of the nodes that need the robot model (docs/ros_interfaces.md):
material, params_file, sigma_a_eq; and loading the HsaParams they select. Shared by every node that
needs the robot model. Also the robot's wiring file (``wiring_file``) of the nodes that map φ to
motors."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from rclpy.parameter import Parameter

from hsa_common.parameters import ParameterValidationError, ParamSpec

if TYPE_CHECKING:
    from hsa_core.model.params import HsaParams
    from hsa_core.model.wiring import Wiring

MATERIALS = ("fpu", "epu")


def check_sigma_a_eq(value: Any) -> str | None:
    """Unset/empty, or two finite positive strains."""
    if value is None or len(value) == 0:
        return None
    if len(value) != 2 or not all(
        isinstance(v, float) and math.isfinite(v) and v > 0.0 for v in value
    ):
        return f"must be empty or 2 finite strains > 0, got {list(value)!r}"
    return None


MODEL_SPECS = (
    ParamSpec(
        "material",
        "fpu",
        "HSA material of the rods, selects the packaged exp2023 parameter set",
        choices=MATERIALS,
        read_only=True,
    ),
    ParamSpec(
        "params_file",
        "",
        "path of a parameter YAML replacing the packaged set (empty = packaged set)",
        read_only=True,
    ),
    ParamSpec(
        "sigma_a_eq",
        Parameter.Type.DOUBLE_ARRAY,
        "[-] calibrated axial rest strains of virtual rods 1 and 2 (unset or empty = from the "
        "parameter set)",
        read_only=True,
        validator=check_sigma_a_eq,
    ),
)


WIRING_SPEC = ParamSpec(
    "wiring_file",
    "",
    "robot wiring YAML: motor IDs, rod and rod sign per motor, nominal neutral "
    "ticks (empty = the packaged lab robot, hsa_core/config/robots/lab.yaml)",
    read_only=True,
)
"""The robot's wiring, shared by every node that maps φ to motors (driver, simulator,
controller)."""


def load_wiring_param(value: str) -> Wiring:
    """The Wiring named by the ``wiring_file`` parameter (raises ParameterValidationError naming
    it)."""
    from hsa_core.model.wiring import WiringError, load_wiring

    try:
        return load_wiring(value)
    except WiringError as exc:
        raise ParameterValidationError(f"parameter 'wiring_file': {exc}") from exc


def load_model(values: dict[str, Any]) -> HsaParams:
    """HsaParams selected by the declared MODEL_SPECS values (``sigma_a_eq`` may be undeclared),
    refusing a set whose material is not ``material`` (raises ParameterValidationError naming the
    parameter)."""
    from hsa_core.model.params import (  # JAX: only nodes that load the model import it
        ParameterError,
        load_params,
    )

    source = values["params_file"] or values["material"]
    sigma_a_eq = values.get("sigma_a_eq")
    overrides = {"sigma_a_eq": list(sigma_a_eq)} if sigma_a_eq else {}
    try:
        params = load_params(source, **overrides)
    except ParameterError as exc:
        name = "params_file" if values["params_file"] else "sigma_a_eq" if overrides else "material"
        raise ParameterValidationError(f"parameter '{name}': {exc}") from exc
    if params.material != values["material"]:
        raise ParameterValidationError(
            f"parameter 'params_file': {source} is a '{params.material}' set but material is "
            f"'{values['material']}'"
        )
    return params
