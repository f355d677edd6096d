"""The worlds between the simulated plant and the controller's model (offline, batched and sim
node): the declared disturbance model and the worlds calibrated on it.

The declared model was fixed before any closed-loop result was looked at, from published sensor and
hardware facts, and is not tuned to make a figure pass. Defaults (``DisturbanceModel()``):

* **Measurement noise** — white Gaussian noise on the mocap planar pose, σ = (0.1 mm, 0.1 mm, 1
  mrad) per sample. OptiTrack rigid-body jitter is of the order of 0.1 mm; 1 mrad is 0.1 mm over a
  100 mm marker base.
* **Latency** — a mocap sample is available to the estimator 6 ms after its stamp (camera latency ≈
  4–6 ms at 200 Hz plus rigid-body solve and transport, ecosystem.md §3.2); a command reaches the
  motors 2 ms after the tick (rclpy hop plus one sync write, ecosystem.md §3.1–3.3).
* **Motor quantization** — goals reach the motors as whole ticks (1 tick = π/2048 rad, truncated
  towards zero by the driver, planning_and_control.md §7) and Present Position reports whole ticks
  (:mod:`hsa_core.sim.world`).
* **Plant/model mismatch** — the plant's nominal stiffnesses (Ŝ_b, Ŝ_sh, Ŝ_a, S_b,sh) are 5 %
  higher, its elongation constant C_ε 3 % lower and its axial rest strains σ_a_eq 0.005 higher than
  the controller's model. These are of the size of the run-to-run σ_a_eq spread (0.97–1.03,
  planning_and_control.md §6.5) and of a modest identification error.
* **Servo speed** — each motor moves towards its goal at no more than the MX-28's no-load speed, 55
  rev/min at 12 V = 5.76 rad/s (ROBOTIS e-Manual, MX-28(2.0) specifications); its position loop is
  otherwise taken as ideal (:mod:`hsa_core.sim.world` gives the evidence). This is a physical limit
  of the hardware, not a tuning knob: without it the simulated plant follows a 25 ms command jump at
  once, which no servo does.

* **Servo position loop and plant damping** — ``servo_time_constant`` (default 0: the shaft slews at
  the cap straight onto the goal) and ``damping_scale`` (default 1: the parameter set's hand-tuned
  damping constants) are the world's parameters that no identification fixed;
  :mod:`hsa_core.apps.calibrate` fits them to the real runs.

* **Rod asymmetry and shear rest strain** — ``rest_strain_difference`` (default 0): the plant's
  σ_a_eq of rod 2 minus that of rod 1 beyond the model's (each rod gets ∓ half of it on top of
  ``rest_strain_offset``); the September 2023 runs calibrated σ_a_eq per rod but gave the controller
  the mean of the two (planning_and_control.md §6.5), so their rods differed by an amount the
  logbook does not keep. ``shear_strain_offset`` (default 0): the plant's shear rest strain σ_sh_eq
  minus the model's. Both, with the other mismatch factors, are fitted to the real robot at rest by
  ``hsa_calibrate --static`` (:mod:`hsa_core.sysid.static_mismatch`; docs/simulation.md).

* **A run's command path** — ``command_queue_depth`` (default 0: each goal is written at its tick)
  and ``command_transaction``: a run whose goals went through the September driver's queue
  (:mod:`hsa_core.sim.command_queue`). A condition of the run's period, set by
  :func:`hsa_core.sim.run_conditions.run_disturbance` from its profile, not a parameter to fit.

:func:`calibrated_world` is a material's calibrated world: the parameters ``hsa_calibrate``
identified (``config/world/<material>.yaml``) and the adopted static mismatch
(``config/world/<material>_static.yaml``) over the declared world; what no fit identified keeps
its declared value. It is the **default world** (:func:`default_world`) of every run that names
none; the declared world stays available by name (``declared``).

``DisturbanceModel.none()`` switches everything off (ideal plant = model, perfect instantaneous
sensing, ideal servos; goals are still whole ticks, as on the bus).

The declaration lives here; :class:`hsa_core.sim.world.World` executes it, for the offline
experiment and the simulator. ``DisturbanceModel.shear_mismatch()`` is the default plus a plant
whose shear stiffness Ŝ_sh is half the model's: the paper reports that the constant-strain model
captures the shear poorly (experiments.md §6); this is the scenario in which the collocated integral
cannot remove the end-effector error and the §3.8 extension is meant to.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import yaml
from numpy.typing import ArrayLike

from hsa_core.model.params import CONFIG_DIR, HsaParams

WORLD_DIR = CONFIG_DIR / "world"
"""The fitted worlds: ``<material>.yaml`` (hsa_calibrate), ``<material>_static.yaml`` (the static
mismatch, ``hsa_calibrate --static --write-world``)."""


@dataclass(frozen=True)
class DisturbanceModel:
    """Noise [m, m, rad], latencies [s], servo speed [rad/s] and time constant [s], plant/model
    mismatch factors, the plant's damping factor, its rods' rest-strain difference and its shear
    rest-strain offset [-] (see module doc)."""

    pose_noise_std: tuple[float, float, float] = (1e-4, 1e-4, 1e-3)
    measurement_latency: float = 0.006
    actuation_latency: float = 0.002
    stiffness_scale: float = 1.05
    elongation_scale: float = 0.97
    rest_strain_offset: float = 0.005
    servo_max_speed: float = 55.0 * 2.0 * math.pi / 60.0
    shear_scale: float = 1.0
    seed: int = 0
    servo_time_constant: float = 0.0
    damping_scale: float = 1.0
    rest_strain_difference: float = 0.0
    shear_strain_offset: float = 0.0
    # a run's command path (run_disturbance): goals through the September queue of this depth
    # (0: written at once) with transactions of command_transaction [s], hsa_core.sim.command_queue
    command_queue_depth: int = 0
    command_transaction: float = 0.0

    def __post_init__(self) -> None:
        """Reject negative noise or latency, non-positive scale factors and a command queue
        without a whole positive number of ms per transaction."""
        if len(self.pose_noise_std) != 3 or min(self.pose_noise_std) < 0.0:
            raise ValueError(f"pose_noise_std must be 3 values >= 0, got {self.pose_noise_std}")
        if self.measurement_latency < 0.0 or self.actuation_latency < 0.0:
            raise ValueError("latencies must be >= 0")
        if self.stiffness_scale <= 0.0 or self.elongation_scale <= 0.0:
            raise ValueError("stiffness_scale and elongation_scale must be > 0")
        if self.shear_scale <= 0.0:
            raise ValueError("shear_scale must be > 0")
        if not (math.isfinite(self.servo_time_constant) and self.servo_time_constant >= 0.0):
            raise ValueError(f"servo_time_constant must be >= 0 s, got {self.servo_time_constant}")
        if not (math.isfinite(self.damping_scale) and self.damping_scale > 0.0):
            raise ValueError(f"damping_scale must be > 0, got {self.damping_scale}")
        if not (
            math.isfinite(self.rest_strain_difference) and math.isfinite(self.shear_strain_offset)
        ):
            raise ValueError("rest_strain_difference and shear_strain_offset must be finite")
        if not self.servo_max_speed > 0.0:
            raise ValueError("servo_max_speed must be > 0 (use math.inf for an ideal servo)")
        depth = self.command_queue_depth
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
            raise ValueError(f"command_queue_depth must be a whole number >= 0, got {depth!r}")
        ms = self.command_transaction * 1e3
        if depth and not (math.isfinite(ms) and ms >= 1.0 and abs(ms - round(ms)) < 1e-9):
            raise ValueError(
                "command_transaction must be a whole number of ms >= 1 with a command queue, "
                f"got {self.command_transaction!r} s"
            )

    @property
    def command_transaction_ms(self) -> int:
        """[ms] the command queue's transaction time on the world's grid (0: no queue)."""
        return round(self.command_transaction * 1e3) if self.command_queue_depth else 0

    @classmethod
    def none(cls) -> DisturbanceModel:
        """No disturbance: the plant is the model, sensing is exact and instantaneous, the servos
        are ideal."""
        return cls((0.0, 0.0, 0.0), 0.0, 0.0, 1.0, 1.0, 0.0, math.inf)

    @classmethod
    def shear_mismatch(cls, seed: int = 0) -> DisturbanceModel:
        """The default disturbance plus a plant with half the model's shear stiffness."""
        return cls(shear_scale=0.5, seed=seed)

    def plant_params(self, model: HsaParams) -> HsaParams:
        """The simulated plant's parameters: the model's with the declared mismatch applied."""
        k = self.stiffness_scale
        return model.replace(
            S_b_hat=np.asarray(model.S_b_hat) * k,
            S_sh_hat=np.asarray(model.S_sh_hat) * k * self.shear_scale,
            S_a_hat=np.asarray(model.S_a_hat) * k,
            S_b_sh=np.asarray(model.S_b_sh) * k,
            C_eps=np.asarray(model.C_eps) * self.elongation_scale,
            sigma_a_eq=np.asarray(model.sigma_a_eq)
            + self.rest_strain_offset
            + np.array([-0.5, 0.5]) * self.rest_strain_difference,
            sigma_sh_eq=np.asarray(model.sigma_sh_eq) + self.shear_strain_offset,
            zeta_b=np.asarray(model.zeta_b) * self.damping_scale,
            zeta_sh=np.asarray(model.zeta_sh) * self.damping_scale,
            zeta_a=np.asarray(model.zeta_a) * self.damping_scale,
        )

    def rng(self) -> np.random.Generator:
        """The seeded noise generator of one run."""
        return np.random.default_rng(self.seed)

    def measure(self, rng: np.random.Generator, chiee: ArrayLike) -> np.ndarray:
        """A noisy mocap sample of the true planar pose."""
        return np.asarray(chiee, dtype=np.float64) + rng.normal(0.0, 1.0, 3) * np.asarray(
            self.pose_noise_std
        )


def rest_world(material: str, seed: int = 0) -> DisturbanceModel:
    """The default world of ``material`` (noise seed ``seed``) with what the robot at rest says:
    its adopted static mismatch (``<material>_static.yaml``) and the mocap's pose noise on x and y
    (``mocap_noise.yaml``, one motion-capture system for every material); the default where neither
    is adopted."""
    values: dict = {}
    static = WORLD_DIR / f"{material}_static.yaml"
    if static.is_file():
        doc = yaml.safe_load(static.read_text())
        if doc["adopted"]:
            values = {name: float(p["value"]) for name, p in doc["fields"].items()}
    noise = WORLD_DIR / "mocap_noise.yaml"
    if noise.is_file():
        doc = yaml.safe_load(noise.read_text())
        if doc["adopted"]:
            theta = DisturbanceModel().pose_noise_std[2]
            values["pose_noise_std"] = (*(float(v) for v in doc["pose_noise_std_xy"]), theta)
    return dataclasses.replace(DisturbanceModel(seed=seed), **values)


def calibrated_world(material: str, seed: int = 0) -> DisturbanceModel:
    """The calibrated world of ``material`` (noise seed ``seed``): its :func:`rest_world` with
    every parameter that ``<material>.yaml`` marks identified; ValueError (one line) for a material
    without a world file."""
    path = WORLD_DIR / f"{material}.yaml"
    if not path.is_file():
        raise ValueError(f"no calibrated world for material {material!r} ({path} is missing)")
    fitted = yaml.safe_load(path.read_text())["parameters"]
    values = {name: float(p["value"]) for name, p in fitted.items() if p["identified"]}
    return dataclasses.replace(rest_world(material, seed), **values)


WORLDS = ("calibrated", "declared", "none", "shear")
"""The worlds a run can name (``hsa_experiment --disturbance``, sim_node's ``disturbance``)."""

DEFAULT_WORLD = "calibrated"
"""The world every run gets unless it names another: the one held against the real robot."""


def named_world(name: str, material: str, seed: int = 0) -> DisturbanceModel:
    """The world ``name`` of :data:`WORLDS` for ``material`` with noise seed ``seed``: the
    material's :func:`calibrated_world`, the declared world (``DisturbanceModel``'s defaults),
    none, or the shear scenario; ValueError (one line) for another name."""
    if name == "calibrated":
        return calibrated_world(material, seed)
    if name == "declared":
        return DisturbanceModel(seed=seed)
    if name == "none":
        return DisturbanceModel.none()
    if name == "shear":
        return DisturbanceModel.shear_mismatch(seed)
    raise ValueError(world_name_problem(name))


def world_name_problem(name: str) -> str | None:
    """Why ``name`` names no world of :data:`WORLDS` (one line), None where it does; the old name
    'default' is told what replaced it."""
    if name in WORLDS:
        return None
    if name == "default":
        return "'default' is now 'declared' (the hand-declared world); the default is 'calibrated'"
    return f"unknown world {name!r}: one of {', '.join(WORLDS)}"


def default_world(material: str, seed: int = 0) -> DisturbanceModel:
    """The world of a run that names none: the material's :func:`calibrated_world` where it has
    one (``<material>.yaml``), else the declared world (a lab's own parameter file)."""
    calibrated = material.isidentifier() and (WORLD_DIR / f"{material}.yaml").is_file()
    return named_world(DEFAULT_WORLD if calibrated else "declared", material, seed)
