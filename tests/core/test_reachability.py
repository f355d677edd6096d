"""hsa_core.task.reachability: the boundary walk of the phi box and the reachable polygon's tests
(inside, distance, contains with margin), against hand-computed geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hsa_core.task.reachability import ReachabilityRegion, boundary_phis

SQUARE = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
L_SHAPE = [(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0, 1.0), (1.0, 2.0), (0.0, 2.0)]  # notch [1, 2]^2


def test_the_boundary_walks_once_around_the_box_each_corner_once() -> None:
    walk = boundary_phis([0.0, 0.0], [1.0, 2.0], n_per_edge=2)
    expected = [
        (0.0, 0.0),
        (0.5, 0.0),
        (1.0, 0.0),
        (1.0, 1.0),
        (1.0, 2.0),
        (0.5, 2.0),
        (0.0, 2.0),
        (0.0, 1.0),
    ]
    np.testing.assert_allclose(walk, expected)
    assert boundary_phis([0.1, 0.2], [3.0, 4.0]).shape == (4 * 32, 2)


def test_inside_and_distance_of_a_square() -> None:
    region = ReachabilityRegion(SQUARE, margin=0.0)
    assert region.inside((0.5, 0.5))
    assert not region.inside((1.5, 0.5)) and not region.inside((0.5, -0.01))
    assert region.distance((0.5, 0.5)) == pytest.approx(0.5)  # to every side
    assert region.distance((0.25, 0.5)) == pytest.approx(0.25)
    assert region.distance((1.5, 0.5)) == pytest.approx(0.5)
    assert region.distance((2.0, 2.0)) == pytest.approx(math.sqrt(2.0))  # to the corner (1, 1)


def test_contains_accepts_within_the_margin_only() -> None:
    region = ReachabilityRegion(SQUARE, margin=0.1)
    assert region.contains((0.5, 0.5))
    assert region.contains((1.05, 0.5)) and not region.contains((1.2, 0.5))
    assert region.contains((1.05, 1.05))  # sqrt(2) * 0.05 = 0.071 from the corner
    assert not region.contains((1.08, 1.08))  # 0.113 from the corner, inside the inflated box
    assert not region.contains((5.0, 5.0))


def test_a_non_convex_polygon_by_the_even_odd_rule() -> None:
    region = ReachabilityRegion(L_SHAPE, margin=0.1)
    assert region.inside((0.5, 1.5)) and region.inside((1.5, 0.5))
    assert not region.inside((1.5, 1.5))  # in the notch, inside the bounding box
    assert region.distance((1.5, 1.5)) == pytest.approx(0.5)
    assert not region.contains((1.5, 1.5)) and region.contains((1.05, 1.5))


def test_the_image_of_a_one_to_one_map_of_the_box() -> None:
    """The module's premise: for phi -> A phi + b one-to-one, the image of the box edges bounds
    the image of the box: inner phis map inside, phis outside the box map outside."""
    a, b = np.array([[0.02, 0.005], [-0.004, 0.03]]), np.array([0.0, 0.1])
    lo, hi = np.zeros(2), np.array([3.0, 3.0])
    region = ReachabilityRegion(boundary_phis(lo, hi, 8) @ a.T + b, margin=0.0)
    rng = np.random.default_rng(0)
    for phi in rng.uniform(0.05, 2.95, size=(50, 2)):
        assert region.contains(a @ phi + b), phi
    for phi in ([-0.5, 1.0], [3.5, 1.0], [1.0, -0.5], [1.0, 3.5], [4.0, 4.0]):
        assert not region.contains(a @ np.asarray(phi) + b), phi


@pytest.mark.parametrize(
    ("boundary", "margin", "message"),
    [
        ([(0.0, 0.0), (1.0, 0.0)], 0.0, "boundary must be (M >= 3, 2) positions, got shape (2, 2)"),
        ([0.0, 1.0, 2.0], 0.0, "boundary must be (M >= 3, 2) positions, got shape (3,)"),
        (SQUARE, -0.1, "margin must be >= 0, got -0.1"),
        (SQUARE, math.nan, "margin must be >= 0, got nan"),
    ],
)
def test_bad_input_is_refused_in_one_line(boundary, margin: float, message: str) -> None:
    with pytest.raises(ValueError) as error:
        ReachabilityRegion(boundary, margin)
    assert str(error.value) == message
