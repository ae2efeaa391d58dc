"""The colour mapping: viridis table and interpolation, normalization, isoline levels and
their detection in images, coordinate colourings; the web viewer carries the same table."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from litege_core.render.colormap import (
    VIRIDIS,
    coordinate_colors,
    isoline_mask,
    nice_step,
    nice_ticks,
    normalize,
    viridis,
)

REPO = Path(__file__).resolve().parents[3]


def test_viridis_table_is_matplotlibs():
    assert VIRIDIS.shape == (256, 3)
    np.testing.assert_allclose(VIRIDIS[0], [0.267004, 0.004874, 0.329415])
    np.testing.assert_allclose(VIRIDIS[128], [0.127568, 0.566949, 0.550556])
    np.testing.assert_allclose(VIRIDIS[255], [0.993248, 0.906157, 0.143936])
    assert not VIRIDIS.flags.writeable


def test_viridis_is_perceptually_ordered():
    """Lightness (Rec. 709 luma as a proxy) rises monotonically from 0 to 1."""
    luma = VIRIDIS @ np.array([0.2126, 0.7152, 0.0722])
    assert np.all(np.diff(luma) > 0)


def test_viewer_carries_the_same_table():
    text = (REPO / "viewer" / "src" / "viridis.js").read_text()
    rows = re.findall(r"\[([0-9.]+), ([0-9.]+), ([0-9.]+)\]", text)
    np.testing.assert_array_equal(np.array(rows, dtype=np.float64), VIRIDIS)


def test_viridis_endpoints_interpolation_and_nan():
    rgb = viridis([0.0, 1.0, 2.0, np.nan], vmin=0.0, vmax=2.0)
    np.testing.assert_allclose(rgb[0], VIRIDIS[0])
    np.testing.assert_allclose(rgb[2], VIRIDIS[255])
    # halfway between entries 127 and 128
    np.testing.assert_allclose(rgb[1], 0.5 * (VIRIDIS[127] + VIRIDIS[128]))
    np.testing.assert_allclose(rgb[3], (0.6, 0.6, 0.6))
    assert viridis(np.zeros((4, 5))).shape == (4, 5, 3)


def test_normalize_clips_and_handles_constant_fields():
    np.testing.assert_allclose(normalize([1.0, 2.0, 3.0]), [0.0, 0.5, 1.0])
    np.testing.assert_allclose(normalize([-1.0, 5.0], vmin=0.0, vmax=4.0), [0.0, 1.0])
    np.testing.assert_allclose(normalize([2.0, 2.0]), [0.0, 0.0])
    out = normalize([0.0, np.inf, 1.0])
    assert np.isnan(out[1]) and out[2] == 1.0


@pytest.mark.parametrize(
    ("span", "target", "expected"),
    [
        (10.0, 10, 1.0),
        (7.3, 10, 1.0),
        (2.0, 10, 0.2),
        (0.03, 10, 0.005),
        (0.02, 10, 0.002),
        (450.0, 5, 100.0),
    ],
)
def test_nice_step(span, target, expected):
    assert nice_step(span, target) == pytest.approx(expected)


def test_nice_step_degenerate_and_ticks():
    assert nice_step(0.0) == 0.0
    assert nice_step(float("nan")) == 0.0
    np.testing.assert_allclose(nice_ticks(0.0, 7.3, 5), [0, 2, 4, 6])
    np.testing.assert_allclose(nice_ticks(0.15, 0.9, 4), [0.2, 0.4, 0.6, 0.8])
    np.testing.assert_allclose(nice_ticks(1.0, 1.0), [1.0])


def test_isolines_of_a_ramp_are_one_pixel_columns():
    values = np.tile(np.arange(20, dtype=np.float64), (6, 1))  # value = x
    mask = isoline_mask(values, 5.0)
    # bands change between x = 4|5, 9|10, 14|15: the pixel of the higher band is marked
    assert np.array_equal(np.flatnonzero(mask.any(axis=0)), [5, 10, 15])
    assert mask[:, [5, 10, 15]].all()


def test_isolines_respect_validity_and_depth_jumps():
    values = np.tile(np.arange(10, dtype=np.float64), (4, 1))
    valid = np.ones_like(values, dtype=bool)
    valid[:, 5] = False
    assert not isoline_mask(values, 5.0, valid).any()  # the only crossing touches a hole
    depth = np.zeros_like(values)
    depth[:, 5:] = 10.0  # an occlusion boundary exactly where the level changes
    assert not isoline_mask(values, 5.0, depth=depth, max_depth_jump=1.0).any()
    assert isoline_mask(values, 5.0, depth=depth).any()  # no threshold: the line is kept
    nan = values.copy()
    nan[:, :] = np.nan
    assert not isoline_mask(nan, 1.0).any()


def test_isoline_arguments_are_checked():
    with pytest.raises(ValueError, match="positive"):
        isoline_mask(np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError, match="image"):
        isoline_mask(np.zeros(3), 1.0)


def test_coordinate_colors_span_the_box():
    points = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 4.0], [0.5, 1.0, 2.0]])
    colors = coordinate_colors(points, low=0.0, high=1.0)
    np.testing.assert_allclose(colors, [[0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5]])
    flat = coordinate_colors(np.zeros((3, 3)))
    assert np.isfinite(flat).all()
    with pytest.raises(ValueError):
        coordinate_colors(np.zeros((3, 2)))
