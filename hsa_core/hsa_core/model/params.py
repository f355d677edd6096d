"""Typed, validated, immutable robot parameters (model.md §2, §5).

The YAML files hold **per-physical-rod** values, exactly as identification produces them; each
per-rod entry is a list of two values, one for each virtual rod [rod 1 at roff = -24 mm (motors
23/24), rod 2 at roff = +24 mm (motors 21/22)]. The loader doubles what model.md §2 says a virtual
rod doubles (rho_r, rho_ec, every stiffness, twist-stiffness and damping constant) and leaves
geometry, C_eps, rho_p and everything else unchanged. `HsaParams` therefore always holds
**virtual-rod** values, which are what every model equation uses.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np
import yaml
from jax import Array
from jax.typing import ArrayLike

from hsa_core import jaxsetup

KAPPA_RULES = ("exact", "exp2023_shift")
"""`exact`: smooth model, no shift (default). `exp2023_shift`: test-compatibility mode of model.md
§8.4(1)."""

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


class ParameterError(ValueError):
    """Raised for an invalid parameter file, override or replacement; the message names the key (and
    file)."""


@dataclasses.dataclass(frozen=True)
class _Spec:
    """Shape, virtual-rod doubling and physical constraint of one numeric parameter."""

    shape: tuple[int, ...]
    doubled: bool = False
    check: str = "finite"  # finite | positive | nonnegative | unit_sign


_SPECS: dict[str, _Spec] = {
    "l": _Spec((), check="positive"),
    "l_pc": _Spec((), check="positive"),
    "l_dc": _Spec((), check="positive"),
    "r_out": _Spec((2,), check="positive"),
    "r_in": _Spec((2,), check="positive"),
    "roff": _Spec((2,)),
    "h": _Spec((2,), check="unit_sign"),
    "platform_size": _Spec((3,), check="positive"),
    "rho_r": _Spec((2,), doubled=True, check="nonnegative"),
    "rho_ec": _Spec((2,), doubled=True, check="nonnegative"),
    "rho_p": _Spec((), check="nonnegative"),
    "g": _Spec((2,)),
    "chiee_off": _Spec((3,)),
    "m_pl": _Spec((), check="nonnegative"),
    "CoG_pl": _Spec((2,)),
    "C_eps": _Spec((2,)),
    "S_b_hat": _Spec((2,), doubled=True),
    "S_sh_hat": _Spec((2,), doubled=True),
    "S_a_hat": _Spec((2,), doubled=True),
    "S_b_sh": _Spec((2,), doubled=True),
    "C_S_b": _Spec((2,), doubled=True),
    "C_S_sh": _Spec((2,), doubled=True),
    "C_S_a": _Spec((2,), doubled=True),
    "zeta_b": _Spec((2,), doubled=True, check="nonnegative"),
    "zeta_sh": _Spec((2,), doubled=True, check="nonnegative"),
    "zeta_a": _Spec((2,), doubled=True, check="nonnegative"),
    "phi_max": _Spec((2,), check="positive"),
    "kappa_b_eq": _Spec((2,)),
    "sigma_sh_eq": _Spec((2,)),
    "sigma_a_eq": _Spec((2,), check="positive"),
}
_META_KEYS = ("material", "kappa_rule")
_OPTIONAL_META = {"kappa_rule": "exact"}


@dataclasses.dataclass(frozen=True, eq=False)
class HsaParams:
    """Virtual-rod parameters of the planar HSA robot; a JAX pytree (float64 leaves, static
    material/kappa_rule).

    The derived-quantity properties use only array methods and operators, so they also work on a
    copy whose leaves are NumPy arrays (the dynamics folds parameter-only terms that way, without
    eager JAX dispatch).
    """

    l: Array
    l_pc: Array
    l_dc: Array
    r_out: Array
    r_in: Array
    roff: Array
    h: Array
    platform_size: Array
    rho_r: Array
    rho_ec: Array
    rho_p: Array
    g: Array
    chiee_off: Array
    m_pl: Array
    CoG_pl: Array
    C_eps: Array
    S_b_hat: Array
    S_sh_hat: Array
    S_a_hat: Array
    S_b_sh: Array
    C_S_b: Array
    C_S_sh: Array
    C_S_a: Array
    zeta_b: Array
    zeta_sh: Array
    zeta_a: Array
    phi_max: Array
    kappa_b_eq: Array
    sigma_sh_eq: Array
    sigma_a_eq: Array
    material: str = "fpu"
    kappa_rule: str = "exact"

    @property
    def xi_eq(self) -> Array:
        """Backbone rest strains [kappa_eq, sigma_sh_eq, sigma_ax_eq] from the per-rod rest strains
        (model.md §5.4)."""
        kappa_eq = jnp.mean(self.kappa_b_eq)
        sigma_ax_eq = jnp.mean(self.sigma_a_eq) - jnp.mean(self.roff * self.kappa_b_eq)
        return jnp.stack([kappa_eq, jnp.mean(self.sigma_sh_eq), sigma_ax_eq])

    @property
    def area(self) -> Array:
        """Cross-section area of one rod, pi (r_out^2 - r_in^2), per virtual rod (2,) [m^2]
        (model.md §5.1)."""
        return np.pi * (self.r_out**2 - self.r_in**2)

    @property
    def second_moment(self) -> Array:
        """Second moment of area of one rod, pi (r_out^4 - r_in^4) / 4, per virtual rod (2,)
        [m^4]."""
        return np.pi * (self.r_out**4 - self.r_in**4) / 4.0

    @property
    def m_dc(self) -> Array:
        """Distal-cap mass per virtual rod, rho_ec l_dc r_out^2 (no pi, the identified convention of
        model.md §5.2)."""
        return self.rho_ec * self.l_dc * self.r_out**2

    @property
    def m_plate(self) -> Array:
        """Mass of the platform plate rho_p w h_p d [kg]."""
        return self.rho_p * self.platform_size.prod()

    @property
    def m_p(self) -> Array:
        """Total platform mass: plate plus both distal caps [kg]."""
        return self.m_plate + self.m_dc.sum()

    @property
    def y_c(self) -> Array:
        """Platform CoG along the platform's local y axis, from the distal end of the active length
        [m]."""
        h_p = self.platform_size[1]
        return (
            self.m_dc.sum() * self.l_dc / 2.0 + self.m_plate * (self.l_dc + h_p / 2.0)
        ) / self.m_p

    @property
    def I_p(self) -> Array:
        """Platform moment of inertia about its CoG (caps as cylinders, plate as a cuboid) [kg
        m^2]."""
        w, h_p, _ = self.platform_size
        y_c = self.y_c
        caps = (
            self.m_dc * ((3.0 * self.r_out**2 + self.l_dc**2) / 12.0 + (self.l_dc / 2.0 - y_c) ** 2)
        ).sum()
        plate = self.m_plate * ((w**2 + h_p**2) / 12.0 + (self.l_dc + h_p / 2.0 - y_c) ** 2)
        return caps + plate

    @property
    def phi_limit(self) -> PhiLimit:
        """The rods' twist limit (phi_max with the handedness h)."""
        return PhiLimit(self.phi_max, self.h)

    def replace(self, **changes: Any) -> HsaParams:
        """Return a copy with fields changed (virtual-rod values, as stored), validated like a
        parameter file."""
        values: dict[str, Any] = {key: np.asarray(getattr(self, key)) for key in _SPECS}
        values.update({key: getattr(self, key) for key in _META_KEYS})
        unknown = sorted(set(changes) - set(values))
        if unknown:
            raise ParameterError(f"replace(): unknown key '{unknown[0]}'")
        values.update(changes)
        return _build(values, source="replace()", double=False)


jax.tree_util.register_dataclass(HsaParams, data_fields=list(_SPECS), meta_fields=list(_META_KEYS))


@dataclasses.dataclass(frozen=True, eq=False)
class PhiLimit:
    """The twist limit of the rods, the one φ limit of the planner, validator, control laws, driver
    and simulations.

    Rod i twists between 0 and h_i·φ_max,i. Three views of these numbers: `box` bounds φ^ss
    (planner, validator, controller setpoints), `clip` bounds the commands φ_cmd = clip(h φ^d, 0,
    φ_max) of the control laws, and `motor` is the one bound [0, motor] of every motor's goal (the
    smaller rod limit: the driver and the motor map).
    """

    phi_max: Array  # per virtual rod [rad], > 0 (NumPy or JAX arrays, also traced ones)
    h: Array  # handedness per virtual rod, ±1

    @property
    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The box of admissible twists φ [rad], per rod: between 0 and h·φ_max (either sign of
        handedness)."""
        signed = np.asarray(self.phi_max) * np.asarray(self.h)
        return np.minimum(0.0, signed), np.maximum(0.0, signed)

    def clip(self, phi: ArrayLike) -> Array:
        """Commands φ_cmd [rad] clipped per rod to [0, φ_max] (jax.numpy: also under jit)."""
        return jnp.clip(phi, 0.0, self.phi_max)

    @property
    def motor(self) -> float:
        """Every motor's goal range is [0, motor] [rad]: the smaller rod limit (one bound for each
        rod)."""
        return float(np.min(np.asarray(self.phi_max)))

    @property
    def handedness(self) -> tuple[int, ...]:
        """Control handedness h of each virtual rod (±1)."""
        return tuple(int(v) for v in np.asarray(self.h))


def _as_array(key: str, value: Any, spec: _Spec, source: str) -> np.ndarray:
    """Convert one raw value to a float64 array and check type, shape, finiteness and its physical
    constraint."""
    where = f"{source}: key '{key}'"
    if value is None or isinstance(value, (bool, np.bool_, str, bytes)):
        raise ParameterError(f"{where}: expected a number or a list of numbers, got {value!r}")
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{where}: not a numeric array ({exc})") from exc
    if arr.dtype.kind not in "iuf":
        raise ParameterError(f"{where}: expected a number or a list of numbers, got {value!r}")
    arr = arr.astype(np.float64)
    if arr.shape != spec.shape:
        raise ParameterError(f"{where}: expected shape {spec.shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{where}: non-finite value {arr.tolist()}")
    if spec.check == "positive" and not np.all(arr > 0.0):
        raise ParameterError(f"{where}: must be > 0, got {arr.tolist()}")
    if spec.check == "nonnegative" and not np.all(arr >= 0.0):
        raise ParameterError(f"{where}: must be >= 0, got {arr.tolist()}")
    if spec.check == "unit_sign" and not np.all(np.abs(arr) == 1.0):
        raise ParameterError(f"{where}: handedness must be +1 or -1, got {arr.tolist()}")
    return arr


def _build(values: Mapping[str, Any], source: str, double: bool) -> HsaParams:
    """Validate a complete raw mapping and construct HsaParams, doubling per-physical-rod values if
    `double`."""
    unknown = sorted(set(values) - set(_SPECS) - set(_META_KEYS))
    if unknown:
        raise ParameterError(f"{source}: unknown key '{unknown[0]}'")
    values = {**_OPTIONAL_META, **values}
    missing = [key for key in (*_SPECS, *_META_KEYS) if key not in values]
    if missing:
        raise ParameterError(f"{source}: missing key '{missing[0]}'")
    material, kappa_rule = values["material"], values["kappa_rule"]
    if not isinstance(material, str) or not material:
        raise ParameterError(
            f"{source}: key 'material': expected a non-empty string, got {material!r}"
        )
    if kappa_rule not in KAPPA_RULES:
        raise ParameterError(
            f"{source}: key 'kappa_rule': expected one of {KAPPA_RULES}, got {kappa_rule!r}"
        )
    arrays = {key: _as_array(key, values[key], spec, source) for key, spec in _SPECS.items()}
    if not np.all(arrays["r_in"] < arrays["r_out"]):
        raise ParameterError(
            f"{source}: key 'r_in': inner radius must be < r_out {arrays['r_out'].tolist()}, got "
            f"{arrays['r_in'].tolist()}"
        )
    leaves = {
        key: jnp.asarray(2.0 * arr if (double and _SPECS[key].doubled) else arr, dtype=jnp.float64)
        for key, arr in arrays.items()
    }
    return HsaParams(**leaves, material=material, kappa_rule=kappa_rule)


def _resolve(name_or_path: str | Path) -> Path:
    """Map "fpu"/"epu" (or any packaged set name) to its YAML file; otherwise treat the argument as
    a path."""
    packaged = CONFIG_DIR / f"{name_or_path}.yaml"
    if (
        isinstance(name_or_path, str)
        and Path(name_or_path).name == name_or_path
        and packaged.is_file()
    ):
        return packaged
    path = Path(name_or_path)
    if not path.is_file():
        raise ParameterError(f"{path}: no such parameter file or packaged set (packaged: fpu, epu)")
    return path


def load_params(name_or_path: str | Path = "fpu", **overrides: Any) -> HsaParams:
    """Load, validate and double a per-physical-rod YAML set; overrides use file (per-physical-rod)
    semantics."""
    jaxsetup.require()
    path = _resolve(name_or_path)
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ParameterError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(raw, dict):
        raise ParameterError(
            f"{path}: expected a mapping of parameter keys, got {type(raw).__name__}"
        )
    unknown = sorted(set(overrides) - set(_SPECS) - set(_META_KEYS))
    if unknown:
        raise ParameterError(f"{path} (overrides): unknown key '{unknown[0]}'")
    source = f"{path} (with overrides {sorted(overrides)})" if overrides else str(path)
    return _build({**raw, **overrides}, source=source, double=True)
