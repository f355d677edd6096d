"""Command-line parsing shared by the hsa-ros CLIs: a bad argument is refused up front, in one line,
with exit 2."""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from hsa_core.runs.profiles import RunProfile
    from hsa_core.runs.reference import ReferenceRun


class ArgumentParser(argparse.ArgumentParser):
    """argparse.ArgumentParser whose errors are one line (``prog: error: ... (see --help)``) and
    exit status 2."""

    def error(self, message: str) -> NoReturn:
        """Print the one-line refusal and exit 2 (argparse would print the whole usage first)."""
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def positive(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = float(text)
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text}")
    return value


def non_negative(text: str) -> float:
    """argparse type: a finite number >= 0."""
    value = float(text)
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def sigma_a_eq(text: str) -> tuple[float, float]:
    """argparse type of --sigma-a-eq: A (both rods) or A,B (rod 1, rod 2), each finite and > 0."""
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if (
        len(parts) not in (1, 2)
        or len(values) != len(parts)
        or not all(0.0 < v < math.inf for v in values)
    ):
        raise argparse.ArgumentTypeError(f"must be A or A,B with finite numbers > 0, got {text}")
    return values[0], values[-1]


def run_profile(text: str) -> RunProfile:
    """argparse type of --profile: a packaged run profile (hsa_core.runs.profiles)."""
    from hsa_core.runs.profiles import load_profile

    try:
        return load_profile(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def world_name(text: str) -> str:
    """argparse type of --disturbance: a name of hsa_core.sim.disturbance.WORLDS; the old name
    'default' is refused with what replaced it."""
    from hsa_core.sim.disturbance import WORLDS

    if text == "default":
        raise argparse.ArgumentTypeError(
            "'default' is now 'declared' (the hand-declared world); the default is 'calibrated'"
        )
    if text not in WORLDS:
        raise argparse.ArgumentTypeError(f"unknown world {text!r}: one of {', '.join(WORLDS)}")
    return text


def reference_run(text: str) -> ReferenceRun:
    """argparse type of --run: a packaged real run of the paper (hsa_core.runs.reference,
    imported on use: it loads JAX)."""
    from hsa_core.runs.reference import load_run

    try:
        return load_run(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_run_conditions(parser: argparse.ArgumentParser) -> None:
    """The run-condition options of every CLI that runs the closed loop (``hsa_experiment``,
    ``run_sim_experiment.py``): ``--profile``, ``--run``, ``--payload``, ``--sigma-a-eq``."""
    from hsa_core.runs.profiles import DEFAULT_PROFILE, profile_names
    from hsa_core.runs.reference import run_names

    parser.add_argument(
        "--profile",
        type=run_profile,
        default=None,
        help=f"run profile, the set-up of a period: {', '.join(profile_names())} (default "
        f"{DEFAULT_PROFILE}): control rate, integrators' step, velocity estimator, sigma_a_eq, "
        "payload (docs/simulation.md, 'Run profiles')",
    )
    parser.add_argument(
        "--run",
        type=reference_run,
        default=None,
        help="replay a real run of the paper with its own conditions (profile, material, law, "
        "gains, sigma_a_eq, payload, setpoints at its real step instants): "
        f"{', '.join(run_names())}",
    )
    parser.add_argument(
        "--payload",
        type=non_negative,
        default=None,
        help="[kg] the plant's payload (default: the profile's or the run's)",
    )
    parser.add_argument(
        "--sigma-a-eq",
        type=sigma_a_eq,
        default=None,
        help="A or A,B: sigma_a_eq of the rods, the model's and the plant's (default: the "
        "profile's or the run's, else the material's)",
    )
