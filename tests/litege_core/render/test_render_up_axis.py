"""The default camera finds the up axis: a z-up animal (TOSCA's convention) is drawn standing,
as the same animal stored y-up is, not vertically or from above."""

import numpy as np
import pytest

from litege_core.io import load_shape
from litege_core.render.figures import render_surface
from litege_core.render.raster import UP_ROTATIONS, VIEWS, detect_up_axis, fit_camera, view_axes
from litege_core.synth import generate_shape

Z_UP = UP_ROTATIONS[2]  # y → z, z → -y: a y-up shape turned z-up


@pytest.fixture(scope="module")
def cat():
    shape = generate_shape("quadruped", "cat", 7, rest_pose=True).to_shape()
    return np.asarray(shape.vertices), np.asarray(shape.faces)


def _silhouette(image) -> tuple[int, int]:
    """Width and height (pixels) of the non-white part of an image."""
    rows, cols = np.nonzero(np.asarray(image).min(axis=2) < 250)
    return int(np.ptp(cols)) + 1, int(np.ptp(rows)) + 1


def test_a_y_up_animal_turned_z_up_is_detected(cat):
    vertices, _ = cat
    assert detect_up_axis(vertices) == 1
    assert detect_up_axis(vertices @ Z_UP.T) == 2


@pytest.mark.parametrize("view", ["side", "three_quarter"])
def test_a_z_up_animal_is_drawn_like_the_y_up_one(cat, view):
    vertices, faces = cat
    upright = render_surface(vertices, faces, size=(160, 120), view=view, ssaa=1)
    turned = render_surface(vertices @ Z_UP.T, faces, size=(160, 120), view=view, ssaa=1)
    width, height = _silhouette(upright)
    assert width > 1.3 * height  # standing: longer than tall
    same = np.abs(np.asarray(upright, dtype=int) - np.asarray(turned, dtype=int)).max(axis=2) < 8
    assert same.mean() > 0.995  # the camera turned with the shape: the same picture
    forced = render_surface(vertices @ Z_UP.T, faces, size=(160, 120), view=view, up_axis=1)
    width, height = _silhouette(forced)
    assert width < height  # what the y-up camera made of it: the animal on its tail


def test_views_turn_with_the_up_axis():
    for view in VIEWS:
        towards, up = view_axes(view, 1)
        turned_towards, turned_up = view_axes(view, 2)
        np.testing.assert_allclose(turned_towards, Z_UP @ towards, atol=1e-12)
        np.testing.assert_allclose(turned_up, Z_UP @ up, atol=1e-12)
        assert turned_towards @ turned_up == pytest.approx(0.0, abs=1e-12)
    towards, up = view_axes((0.0, 0.0, 1.0), 2)  # a direction along the up axis itself
    np.testing.assert_allclose(towards, [0, 0, 1])
    assert abs(up @ towards) < 1e-12 and np.linalg.norm(up) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        view_axes("side", 3)


def test_explicit_up_axis_overrides_detection(cat):
    vertices, _ = cat
    camera = fit_camera(vertices @ Z_UP.T, (100, 100), "side", up_axis=1)
    np.testing.assert_allclose(camera.up, [0, 1, 0], atol=1e-12)
    camera = fit_camera(vertices @ Z_UP.T, (100, 100), "side")
    np.testing.assert_allclose(camera.up, [0, 0, 1], atol=1e-12)


def test_real_shapes_up_axes(eval_data):
    cat0 = load_shape(eval_data / "tosca_5k" / "cat0.off").vertices  # TOSCA: z-up
    human = load_shape(eval_data / "faust_5k" / "tr_reg_080.off").vertices  # FAUST: y-up
    assert detect_up_axis(cat0) == 2
    assert detect_up_axis(human) == 1
