"""Reference trajectories of the experiments: step lists, image-contour references and parametric
shapes.

Every reference is a ``TimedReference``: setpoint j (an EE position p^d_j = [x, y] in {0}, m)
becomes active at t_j (s, t_0 = 0) and stays active until t_{j+1} (zero-order hold). After the last
setpoint's slot, at t ≥ ``duration``, the reference is finished; ``sample`` keeps returning the last
setpoint (hold, as experiments.md §2 requires).

* **Steps** (experiments.md §2): the FPU list of 2023-09-25 or the EPU list of 2023-10-19, 10 s per
  setpoint, so 11 setpoints last 110 s.
* **Image contours** (experiments.md §3), ``contour_reference``:
  1. read the image (colour) and convert it to grey; optionally crop a centred square whose side is
     the smaller image dimension (the height for the landscape star asset);
  2. threshold: pixels > ``threshold`` are the shape, or pixels ≤ ``threshold`` with ``invert``
     (defaults 140, inverted; the star used 128, not inverted);
  3. external contours without approximation (``cv2.findContours``, RETR_EXTERNAL,
     CHAIN_APPROX_NONE); the first one is used. OpenCV starts it at the top-most, then left-most
     boundary pixel and traces it counter-clockwise as displayed;
  4. subtract the centroid of the contour's moments, truncated to whole pixels: (⌊m10/m00⌋,
     ⌊m01/m00⌋);
  5. divide by the largest absolute pixel coordinate (so all lie in [−1, 1], aspect ratio kept);
  6. negate y (image y points down); the traced order is now counter-clockwise, i.e. of positive
     signed area, in the (x, y) plane;
  7. keep every k-th point, starting with the first;
  8. optionally flip (multiply by −1; the flame, CSAIL and bat assets were flipped, the star not);
  9. p^d_j = centroid_robot + r_max · p_norm,j.

  ``direction`` then selects the order: "traced" (as above, the original behaviour), "ccw" or "cw"
  (signed area in {0}'s x-y plane positive or negative); reversing keeps the first point and visits
  the others backwards. Setpoints are spaced by 1/rate (8 Hz default).
* **Parametric shapes**: a regular 5-pointed star outline (inner/outer radius ratio of the pentagram
  by default) and a circle, sampled at points equally spaced by arc length, starting at angle
  ``start_angle`` from +x towards +y.

Safe range: the reachable workspace allows contours of radius ≤ 0.03 m around y ≈ 0.1285 m
(experiments.md §3). A radius outside (0, R_MAX_SAFE] raises ``ValueError``; raise ``max_radius``
explicitly to go beyond it.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

R_MAX_SAFE = 0.030  # m, experiments.md §3
STEP_PERIOD = 10.0  # s per setpoint, experiments.md §2
CONTOUR_RATE = 8.0  # Hz, experiments.md §3

FPU_STEPS_20230925 = (
    (0.0, 0.120),
    (0.00479247, 0.12781018),
    (-0.035, 0.122),
    (-0.00782133, 0.13024847),
    (0.00823294, 0.114643),
    (-0.01417039, 0.12388105),
    (0.0, 0.140),
    (0.02524261, 0.1304036),
    (-0.0059703, 0.13986947),
    (0.0073023, 0.11479653),
    (0.00567301, 0.1271345),
)
EPU_STEPS_20231019 = (
    (0.01567931, 0.13496604),
    (-0.01137064, 0.13488599),
    (-0.00210567, 0.12011204),
    (-0.00869464, 0.13911694),
    (-0.00929787, 0.12710664),
    (-0.00304799, 0.12364617),
    (0.00478033, 0.12777372),
    (-0.02880408, 0.12547507),
    (0.02296768, 0.12596894),
    (0.01681273, 0.1245412),
    (-0.00122529, 0.14039634),
)
STEP_LISTS = {"fpu": FPU_STEPS_20230925, "epu": EPU_STEPS_20231019}
# inner / outer radius
PENTAGRAM_RATIO = math.cos(math.radians(72.0)) / math.cos(math.radians(36.0))


@dataclass(frozen=True, eq=False)
class TimedReference:
    """Setpoints p_des[j] (m, in {0}) active from t[j] (s) on; finished at t ≥ duration (zero-order
    hold)."""

    t: np.ndarray
    p_des: np.ndarray
    name: str
    duration: float

    def __post_init__(self) -> None:
        """Validate shapes and times and freeze the arrays."""
        t = np.array(self.t, dtype=np.float64)
        p_des = np.array(self.p_des, dtype=np.float64)
        if t.ndim != 1 or t.size == 0 or p_des.shape != (t.size, 2):
            raise ValueError(
                f"need t (N,) and p_des (N, 2) with N >= 1, got {t.shape} and {p_des.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p_des))):
            raise ValueError("t and p_des must be finite")
        if t[0] != 0.0 or np.any(np.diff(t) <= 0.0) or not self.duration > t[-1]:
            raise ValueError("need t[0] = 0, strictly increasing t and duration > t[-1]")
        t.setflags(write=False)
        p_des.setflags(write=False)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "p_des", p_des)

    def __len__(self) -> int:
        """Number of setpoints."""
        return self.t.size

    def index(self, t: ArrayLike) -> np.ndarray | int:
        """Index of the setpoint active at time(s) t ≥ 0 (the last one after the end)."""
        t_arr = np.asarray(t, dtype=np.float64)
        if np.any(t_arr < 0.0) or not np.all(np.isfinite(t_arr)):
            raise ValueError("a reference is defined only for finite t >= 0")
        idx = np.searchsorted(self.t, t_arr, side="right") - 1
        return int(idx) if idx.ndim == 0 else idx

    def sample(self, t: ArrayLike) -> np.ndarray:
        """Active setpoint(s) at time(s) t: (2,) for a scalar t, (M, 2) for M times."""
        return self.p_des[self.index(t)]

    def finished(self, t: float) -> bool:
        """True once the last setpoint's slot has ended (the last setpoint is held)."""
        return t >= self.duration


def _check_radius(radius: float, max_radius: float) -> None:
    """Reject radii outside the documented safe range (0, max_radius]."""
    if not 0.0 < radius <= max_radius:
        raise ValueError(
            f"radius {radius} m outside the safe range (0, {max_radius}] m (experiments.md §3: "
            f"r_max <= {R_MAX_SAFE} m around y = 0.1285 m); pass max_radius to override "
            "deliberately"
        )


def _timed(points: np.ndarray, period: float, name: str) -> TimedReference:
    """Reference visiting the points one per period [s]."""
    if not (period > 0.0 and math.isfinite(period)):
        raise ValueError(f"period must be finite and > 0, got {period}")
    n = points.shape[0]
    return TimedReference(np.arange(n) * period, points, name, n * period)


def _period(rate: float) -> float:
    """Setpoint period [s] of a positive, finite rate [Hz]."""
    if not (rate > 0.0 and math.isfinite(rate)):
        raise ValueError(f"rate must be finite and > 0, got {rate}")
    return 1.0 / rate


class Direction(enum.StrEnum):
    """Order of a contour's points: as traced, counter-clockwise or clockwise in x-y of {0}."""

    TRACED = "traced"
    CCW = "ccw"
    CW = "cw"


TURNING = (Direction.CCW, Direction.CW)
"""The directions of a generated shape (circle, star)."""


def _signed_area(points: np.ndarray) -> float:
    """Shoelace signed area of a closed polygon (positive = counter-clockwise in x-y)."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _orient(points: np.ndarray, direction: Direction | str) -> np.ndarray:
    """Points in the requested order; a reversal keeps the first point."""
    if direction not in tuple(Direction):
        raise ValueError(f"direction must be 'traced', 'ccw' or 'cw', got {direction!r}")
    direction = Direction(direction)
    ccw = _signed_area(points) > 0.0
    if direction is Direction.TRACED or points.shape[0] < 3 or ccw == (direction is Direction.CCW):
        return points
    return np.concatenate([points[:1], points[:0:-1]])


def step_reference(
    points: str | ArrayLike = "fpu", period: float = STEP_PERIOD, name: str | None = None
) -> TimedReference:
    """Step reference: "fpu" (2023-09-25) or "epu" (2023-10-19) list of experiments.md §2, or given
    (N, 2) points."""
    if isinstance(points, str):
        if points not in STEP_LISTS:
            raise ValueError(f"unknown step list {points!r}; choose from {sorted(STEP_LISTS)}")
        name = name or f"{points}_steps"
        points = STEP_LISTS[points]
    return _timed(np.asarray(points, dtype=np.float64), period, name or "steps")


def contour_reference(
    image_path: str | Path,
    centroid: ArrayLike = (0.0, 0.1285),
    r_max: float = 0.013,
    k: int = 5,
    rate: float = CONTOUR_RATE,
    threshold: int = 140,
    invert: bool = True,
    crop_square: bool = False,
    flip: bool = False,
    direction: Direction | str = Direction.TRACED,
    max_radius: float = R_MAX_SAFE,
    name: str | None = None,
) -> TimedReference:
    """Reference along the first external contour of a binary shape in an image (pipeline: module
    docstring)."""
    _check_radius(r_max, max_radius)
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    path = Path(image_path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    # OpenCV only where an image is read: the sequencer and the planner load this module without it
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"cannot read image {path} (not a supported image format?)")
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if crop_square:
        rows, cols = grey.shape
        side = min(rows, cols)
        r0, c0 = (rows - side) // 2, (cols - side) // 2
        grey = grey[r0 : r0 + side, c0 : c0 + side]
    mode = cv2.THRESH_BINARY_INV if invert else cv2.THRESH_BINARY
    _, binary = cv2.threshold(grey, threshold, 255, mode)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise ValueError(f"no contour found in {path} (threshold {threshold}, invert={invert})")
    contour = contours[0]
    moments = cv2.moments(contour)
    if moments["m00"] == 0.0:
        raise ValueError(f"first contour in {path} encloses no area")
    m00 = moments["m00"]
    pixel_centroid = np.array([math.floor(moments["m10"] / m00), math.floor(moments["m01"] / m00)])
    p = contour[:, 0, :].astype(np.float64) - pixel_centroid
    p /= np.max(np.abs(p))
    p[:, 1] *= -1.0
    p = p[::k]
    if flip:
        p = -p
    p_des = np.asarray(centroid, dtype=np.float64) + r_max * _orient(p, direction)
    return _timed(p_des, _period(rate), name or path.stem)


def circle_reference(
    centroid: ArrayLike = (0.0, 0.1285),
    radius: float = 0.013,
    n_points: int = 200,
    rate: float = CONTOUR_RATE,
    start_angle: float = 0.0,
    direction: Direction | str = Direction.CCW,
    max_radius: float = R_MAX_SAFE,
) -> TimedReference:
    """Circle of the given radius [m] around the centroid, n_points equally spaced, ccw or cw in
    {0}."""
    _check_radius(radius, max_radius)
    if direction not in TURNING or n_points < 3:
        raise ValueError("need direction 'ccw' or 'cw' and n_points >= 3")
    sense = 1.0 if Direction(direction) is Direction.CCW else -1.0
    angle = start_angle + sense * 2.0 * math.pi * np.arange(n_points) / n_points
    p_des = np.asarray(centroid, dtype=np.float64) + radius * np.column_stack(
        [np.cos(angle), np.sin(angle)]
    )
    return _timed(p_des, _period(rate), "circle")


def star_reference(
    centroid: ArrayLike = (0.0, 0.1285),
    radius: float = 0.013,
    n_points: int = 500,
    rate: float = CONTOUR_RATE,
    inner_ratio: float = PENTAGRAM_RATIO,
    start_angle: float = math.pi / 2,
    direction: Direction | str = Direction.CCW,
    max_radius: float = R_MAX_SAFE,
) -> TimedReference:
    """Outline of a 5-pointed star (outer tip radius [m], tip at start_angle), n_points equally
    spaced by arc length."""
    _check_radius(radius, max_radius)
    if direction not in TURNING or n_points < 10 or not 0.0 < inner_ratio < 1.0:
        raise ValueError("need direction 'ccw' or 'cw', n_points >= 10 and 0 < inner_ratio < 1")
    sense = 1.0 if Direction(direction) is Direction.CCW else -1.0
    angle = start_angle + sense * np.pi / 5.0 * np.arange(11)
    r = radius * np.where(np.arange(11) % 2 == 0, 1.0, inner_ratio)
    vertices = np.column_stack([r * np.cos(angle), r * np.sin(angle)])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(vertices, axis=0), axis=1))])
    s = arc[-1] * np.arange(n_points) / n_points
    outline = np.column_stack(
        [np.interp(s, arc, vertices[:, 0]), np.interp(s, arc, vertices[:, 1])]
    )
    return _timed(np.asarray(centroid, dtype=np.float64) + outline, _period(rate), "star")
