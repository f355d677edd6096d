"""Every run of the paper by its bag name, replayable with its own conditions (no ROS).

The four packaged reference runs (:mod:`hsa_core.runs.reference`) carry their traces and their real
step instants. The paper's other runs (spec experiments.md §7: the 0.2 kg payload steps, the
star, flame, CSAIL and bat contours, the other EPU steps) are known by their conditions only
(``config/realdata/paper_runs.yaml``, sources cited there): law, gains, σ_a,eq (the authors'
logbook), payload, date, the run profile of the period and the trajectory. A step run plays the
material's list at one point every 10 s. A contour run plays its contour at 8 Hz (experiments.md
§3), traced from the original image, which is not packaged: :func:`replayable` takes the folder that
holds it.

:func:`replayable` returns what :func:`hsa_core.sim.experiment.replay_config` and
:func:`hsa_core.sim.run_conditions.run_schedule` take (:class:`Replayable`): a packaged
:class:`~hsa_core.runs.reference.ReferenceRun`, else a :class:`CataloguedRun`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import yaml

from hsa_core.runs import reference
from hsa_core.runs.reference import RunConditions
from hsa_core.task import trajectories
from hsa_core.task.trajectories import TimedReference

CATALOGUE_FILE = reference.DATA_DIR / "paper_runs.yaml"
"""The conditions of the paper's runs that are not packaged with traces."""


class Replayable(Protocol):
    """A paper run as a replay needs it: its conditions and its setpoints in time."""

    @property
    def conditions(self) -> RunConditions:
        """The run's logbook conditions."""
        ...

    def timed_reference(self) -> TimedReference:
        """The run's setpoints at their instants."""
        ...


@dataclass(frozen=True)
class Contour:
    """One contour of experiments.md §3: the original image file, every ``k``-th contour point,
    ``r_max`` [m] around ``centroid`` [m], the pipeline's grey ``threshold``, ``invert`` (a dark
    shape), ``crop_square`` (the star) and ``flip`` (flame, CSAIL, bat)."""

    image: str
    k: int
    r_max: float
    centroid: tuple[float, float]
    threshold: int
    invert: bool
    crop_square: bool
    flip: bool


@dataclass(frozen=True)
class CataloguedRun:
    """A paper run known by its conditions only: ``contour`` None plays the material's step list
    (one point every 10 s), else that contour at 8 Hz from the image in ``image_dir``."""

    conditions: RunConditions
    contour: Contour | None
    image_dir: Path | None = None

    def image_path(self) -> Path:
        """The contour's image file in ``image_dir``; ValueError (one line) where it is missing."""
        if self.contour is None:
            raise ValueError(f"{self.conditions.bag} is a step run: it has no image")
        name = self.contour.image
        if self.image_dir is None or not (self.image_dir / name).is_file():
            where = "no --image-dir given" if self.image_dir is None else f"not in {self.image_dir}"
            raise ValueError(
                f"{self.conditions.bag} traces the contour of {name} (tud-phi/hsa-planar-control, "
                f"assets/; not packaged): {where}"
            )
        return self.image_dir / name

    def timed_reference(self) -> TimedReference:
        """The step list every 10 s, or the contour at 8 Hz traced as the original did."""
        if self.contour is None:
            return trajectories.step_reference(
                self.conditions.material, name=f"{self.conditions.bag}_steps"
            )
        c = self.contour
        return trajectories.contour_reference(
            self.image_path(),
            centroid=c.centroid,
            r_max=c.r_max,
            k=c.k,
            threshold=c.threshold,
            invert=c.invert,
            crop_square=c.crop_square,
            flip=c.flip,
            name=self.conditions.bag,
        )


def run_names() -> tuple[str, ...]:
    """Every run of the paper this package can replay: the packaged ones and the catalogued ones,
    oldest first."""
    return tuple(sorted({*reference.run_names(), *_catalogue()[0]}))


def replayable(bag: str, image_dir: Path | None = None) -> Replayable:
    """The run ``bag``: the packaged reference run, else the catalogued one (its contour's image in
    ``image_dir``); ValueError (one line) for a name the paper does not have."""
    if bag in reference.run_names():
        return reference.load_run(bag)
    runs, contours = _catalogue()
    if bag not in runs:
        raise ValueError(f"unknown run of the paper {bag!r}; known: {', '.join(run_names())}")
    entry = runs[bag]
    kind = str(entry["trajectory"])
    contour = None if kind == "steps" else contours[kind]
    return CataloguedRun(reference.conditions_of(bag, entry), contour, image_dir)


@functools.cache
def _catalogue() -> tuple[dict[str, dict], dict[str, Contour]]:
    """paper_runs.yaml: bag → its entry as written; contour name → :class:`Contour`."""
    raw = yaml.safe_load(CATALOGUE_FILE.read_text())
    contours = {
        name: Contour(
            str(c["image"]),
            int(c["k"]),
            float(c["r_max"]),
            (float(c["centroid"][0]), float(c["centroid"][1])),
            int(c["threshold"]),
            bool(c["invert"]),
            bool(c["crop_square"]),
            bool(c["flip"]),
        )
        for name, c in raw["contours"].items()
    }
    runs = {str(bag): entry for bag, entry in raw["runs"].items()}
    unknown = {str(e["trajectory"]) for e in runs.values()} - {"steps", *contours}
    if unknown:
        raise ValueError(f"{CATALOGUE_FILE}: unknown trajectories {sorted(unknown)}")
    return runs, contours
