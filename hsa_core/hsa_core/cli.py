"""Command-line parsing shared by the hsa-ros CLIs: a bad argument is refused up front, in one line,
with exit 2."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from hsa_core.runs.catalogue import Replayable
    from hsa_core.runs.profiles import RunProfile


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


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
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
    from hsa_core.sim.disturbance import world_name_problem

    problem = world_name_problem(text)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return text


def paper_run(text: str) -> Replayable:
    """argparse type of --run: a run of the paper (hsa_core.runs.catalogue, imported on use: it
    loads JAX); a contour run's image folder is added by :func:`run_with_images`."""
    from hsa_core.runs.catalogue import replayable

    try:
        return replayable(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run_with_images(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Give ``args.run`` the folder ``--image-dir`` and check that a contour run's image is there
    (a one-line refusal through ``parser`` where it is not)."""
    from hsa_core.runs.catalogue import CataloguedRun

    run = args.run
    if not isinstance(run, CataloguedRun) or run.contour is None:
        if args.image_dir is not None:
            parser.error("--image-dir applies to a contour run of --run only")
        return
    args.run = dataclasses.replace(run, image_dir=args.image_dir)
    try:
        args.run.image_path()
    except ValueError as exc:
        parser.error(f"argument --run: {exc}")


def add_run_conditions(parser: argparse.ArgumentParser) -> None:
    """The run-condition options of every CLI that runs the closed loop (``hsa_experiment``,
    ``run_sim_experiment.py``): ``--profile``, ``--run``, ``--payload``, ``--sigma-a-eq``."""
    from hsa_core.runs.catalogue import run_names
    from hsa_core.runs.profiles import DEFAULT_PROFILE, profile_names

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
        type=paper_run,
        default=None,
        help="replay a run of the paper with its own conditions (profile, material, law, gains, "
        "sigma_a_eq, payload, setpoints; a packaged run's at its real step instants): "
        f"{', '.join(run_names())}",
    )
    parser.add_argument(
        "--image-dir",
        type=Path,
        default=None,
        help="folder holding the original image of a contour run of --run (star.png, "
        "tud_flame.jpeg, mit_csail.png, bat.png of tud-phi/hsa-planar-control, assets/)",
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
