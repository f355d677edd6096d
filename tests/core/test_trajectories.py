"""Tests of hsa_core.task.trajectories: step lists, image-contour and parametric references
(experiments.md §2–§3)."""

import math

import cv2
import numpy as np
import pytest

from hsa_core.task.trajectories import (
    R_MAX_SAFE,
    Direction,
    TimedReference,
    circle_reference,
    contour_reference,
    star_reference,
    step_reference,
)


def shoelace(p):
    """Signed area of a closed polygon (positive: counter-clockwise in x-y)."""
    return 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - p[:, 1] * np.roll(p[:, 0], -1))


def write_image(path, image):
    assert cv2.imwrite(str(path), image)
    return path


@pytest.fixture
def circle_png(tmp_path):
    """Dark filled circle, radius 100 px, centre (150, 120), on a light background
    (inverted-threshold asset)."""
    img = np.full((260, 320, 3), 255, np.uint8)
    cv2.circle(img, (150, 120), 100, (0, 0, 0), -1)
    return write_image(tmp_path / "circle.png", img)


@pytest.fixture
def l_shape_png(tmp_path):
    """Bright L shape on black: a tall bar on the left (x 40–79, y 20–219) and a foot to the right
    (y 180–219)."""
    img = np.zeros((240, 240), np.uint8)
    img[20:220, 40:80] = 255
    img[180:220, 40:200] = 255
    return write_image(tmp_path / "l_shape.png", img)


def test_fpu_step_list_as_in_experiments():
    ref = step_reference("fpu")
    assert len(ref) == 11 and ref.duration == 110.0 and ref.name == "fpu_steps"
    np.testing.assert_array_equal(ref.t, np.arange(11) * 10.0)
    np.testing.assert_array_equal(ref.p_des[0], [0.0, 0.120])
    np.testing.assert_array_equal(ref.p_des[1], [0.00479247, 0.12781018])
    np.testing.assert_array_equal(ref.p_des[2], [-0.035, 0.122])
    # 09-25 list, not the 09-26 variant
    np.testing.assert_array_equal(ref.p_des[4], [0.00823294, 0.114643])
    np.testing.assert_array_equal(ref.p_des[9], [0.0073023, 0.11479653])
    np.testing.assert_array_equal(ref.p_des[10], [0.00567301, 0.1271345])


def test_epu_step_list_as_in_experiments():
    ref = step_reference("epu")
    assert len(ref) == 11 and ref.duration == 110.0
    np.testing.assert_array_equal(ref.p_des[0], [0.01567931, 0.13496604])
    np.testing.assert_array_equal(ref.p_des[7], [-0.02880408, 0.12547507])
    np.testing.assert_array_equal(ref.p_des[10], [-0.00122529, 0.14039634])


def test_zero_order_hold_and_finish():
    ref = step_reference("fpu")
    np.testing.assert_array_equal(ref.sample(0.0), ref.p_des[0])
    np.testing.assert_array_equal(ref.sample(9.999), ref.p_des[0])
    np.testing.assert_array_equal(ref.sample(10.0), ref.p_des[1])
    np.testing.assert_array_equal(ref.sample([5.0, 55.0, 1000.0]), ref.p_des[[0, 5, 10]])
    assert ref.index(105.0) == 10 and not ref.finished(109.9) and ref.finished(110.0)
    np.testing.assert_array_equal(ref.sample(500.0), ref.p_des[-1])  # the last setpoint is held
    with pytest.raises(ValueError):
        ref.sample(-0.1)


def test_custom_steps_and_invalid_references():
    ref = step_reference([[0.0, 0.12], [0.01, 0.13]], period=5.0, name="two")
    assert ref.name == "two" and ref.duration == 10.0
    with pytest.raises(ValueError):
        step_reference("xyz")
    with pytest.raises(ValueError):
        TimedReference(np.array([0.0, 1.0, 1.0]), np.zeros((3, 2)), "bad", 2.0)
    with pytest.raises(ValueError):
        TimedReference(np.array([0.0]), np.zeros((1, 3)), "bad", 1.0)
    assert not ref.p_des.flags.writeable


def test_contour_of_circle_lies_on_r_max_around_centroid(circle_png):
    centroid, r_max = np.array([0.0, 0.1285]), 0.02
    ref = contour_reference(circle_png, centroid=centroid, r_max=r_max, k=1)
    radius_px = 100
    dist = np.linalg.norm(ref.p_des - centroid, axis=1)
    # boundary pixels lie within a pixel of the radius; the centroid is truncated to whole pixels (≤
    # 1 px more)
    assert np.all(np.abs(dist - r_max) <= 2.0 * r_max / radius_px)
    # normalised by the max abs coordinate
    assert np.max(np.abs(ref.p_des - centroid)) == pytest.approx(r_max)
    assert 2 * math.pi * radius_px * 0.7 < len(ref) < 2 * math.pi * radius_px * 1.1
    assert ref.t[1] == pytest.approx(1 / 8.0) and ref.duration == pytest.approx(len(ref) / 8.0)


def test_subsampling_keeps_every_kth_point(circle_png):
    full = contour_reference(circle_png, k=1)
    every5 = contour_reference(circle_png, k=5)
    np.testing.assert_array_equal(every5.p_des, full.p_des[::5])
    assert len(every5) == math.ceil(len(full) / 5)


def test_contour_orientation_start_and_flip_on_l_shape(l_shape_png):
    centroid, r_max = np.array([0.0, 0.13]), 0.01
    ref = contour_reference(
        l_shape_png, centroid=centroid, r_max=r_max, k=1, threshold=128, invert=False
    )
    p = (ref.p_des - centroid) / r_max
    # moments of the L (two rectangles, pixel-centre coordinates): area-weighted centroid
    a1, c1 = 40 * 200, np.array([59.5, 119.5])
    a2, c2 = 120 * 40, np.array([139.5, 199.5])
    pix_centroid = np.floor((a1 * c1 + a2 * c2) / (a1 + a2))
    # the foot extends to the right (+x) and lies at the bottom of the image, which is −y after
    # negating y
    far = np.array([199.0, 219.0]) - pix_centroid
    scale = np.max(np.abs(np.array([[40, 20], [199, 219]]) - pix_centroid))
    assert np.min(np.linalg.norm(p - far * [1, -1] / scale, axis=1)) < 2.0 / scale
    # the first point is the raster-first boundary pixel (top row, left-most): top-left corner of
    # the bar
    np.testing.assert_allclose(
        p[0], (np.array([40.0, 20.0]) - pix_centroid) * [1, -1] / scale, atol=1.5 / scale
    )
    assert shoelace(p) > 0  # traced order is counter-clockwise in x-y after negating y
    flipped = contour_reference(
        l_shape_png, centroid=centroid, r_max=r_max, k=1, threshold=128, invert=False, flip=True
    )
    np.testing.assert_allclose(flipped.p_des - centroid, -(ref.p_des - centroid))
    assert shoelace(flipped.p_des - centroid) > 0  # a point reflection keeps the orientation


def test_direction_option(l_shape_png):
    kwargs = dict(k=3, threshold=128, invert=False)
    traced = contour_reference(l_shape_png, **kwargs)
    cw = contour_reference(l_shape_png, direction="cw", **kwargs)
    ccw = contour_reference(l_shape_png, direction="ccw", **kwargs)
    np.testing.assert_array_equal(ccw.p_des, traced.p_des)
    assert shoelace(cw.p_des) < 0 and shoelace(ccw.p_des) > 0
    np.testing.assert_array_equal(cw.p_des[0], traced.p_des[0])  # same start point
    np.testing.assert_array_equal(cw.p_des[1:], traced.p_des[:0:-1])
    members = contour_reference(l_shape_png, direction=Direction.CW, **kwargs)
    np.testing.assert_array_equal(members.p_des, cw.p_des)  # the enum member and its name agree
    assert shoelace(circle_reference(direction=Direction.CW).p_des) < 0


def test_crop_to_centred_square(tmp_path):
    # landscape image 200 × 400 with a bright square in the centre and a distractor near the left
    # edge
    img = np.zeros((200, 400), np.uint8)
    img[60:140, 160:240] = 255
    img[10:30, 5:40] = 255
    path = write_image(tmp_path / "wide.png", img)
    cropped = contour_reference(
        path, k=1, threshold=128, invert=False, crop_square=True, r_max=0.01
    )
    d = cropped.p_des - [0.0, 0.1285]
    # only the central square remains
    assert np.max(np.abs(d)) == pytest.approx(0.01) and len(cropped) == 4 * 79


def test_clear_errors(tmp_path, circle_png):
    with pytest.raises(FileNotFoundError):
        contour_reference(tmp_path / "missing.png")
    garbage = tmp_path / "garbage.png"
    garbage.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="cannot read"):
        contour_reference(garbage)
    blank = write_image(tmp_path / "blank.png", np.full((50, 50), 255, np.uint8))
    with pytest.raises(ValueError, match="no contour"):
        contour_reference(blank)
    for r_max in (0.0, -0.01, R_MAX_SAFE + 1e-4):
        with pytest.raises(ValueError, match="safe range"):
            contour_reference(circle_png, r_max=r_max)
    # deliberate override
    assert len(contour_reference(circle_png, r_max=0.04, max_radius=0.05)) > 0
    with pytest.raises(ValueError):
        contour_reference(circle_png, k=0)
    with pytest.raises(ValueError):
        contour_reference(circle_png, rate=0.0)
    with pytest.raises(ValueError):
        contour_reference(circle_png, direction="sideways")


def test_circle_reference_geometry():
    centroid = np.array([0.001, 0.128])
    ref = circle_reference(centroid=centroid, radius=0.015, n_points=100, rate=4.0)
    np.testing.assert_allclose(np.linalg.norm(ref.p_des - centroid, axis=1), 0.015)
    np.testing.assert_allclose(ref.p_des[0], centroid + [0.015, 0.0])
    assert shoelace(ref.p_des - centroid) > 0 and ref.duration == 25.0
    assert shoelace(circle_reference(direction="cw").p_des) < 0
    with pytest.raises(ValueError):
        circle_reference(radius=0.05)


def test_star_reference_geometry():
    centroid = np.array([0.0, 0.127])
    ref = star_reference(centroid=centroid, radius=0.013, n_points=1000)
    d = ref.p_des - centroid
    r = np.linalg.norm(d, axis=1)
    inner = 0.013 * math.cos(math.radians(72)) / math.cos(math.radians(36))  # regular pentagram
    assert r.max() == pytest.approx(0.013) and r.min() == pytest.approx(inner, rel=2e-3)
    np.testing.assert_allclose(d[0], [0.0, 0.013], atol=1e-15)  # first tip at +y
    step = np.linalg.norm(np.diff(np.vstack([d, d[:1]]), axis=0), axis=1)
    perimeter = 10 * math.sqrt(0.013**2 + inner**2 - 2 * 0.013 * inner * math.cos(math.radians(36)))
    assert step.sum() == pytest.approx(perimeter, rel=1e-3)
    assert shoelace(d) > 0
    # five-fold symmetry: rotating by 72° maps the tips onto tips
    tips = d[np.isclose(r, 0.013)]
    angles = np.sort(np.mod(np.arctan2(tips[:, 1], tips[:, 0]), 2 * math.pi))
    np.testing.assert_allclose(np.diff(angles), 2 * math.pi / 5, atol=1e-9)
