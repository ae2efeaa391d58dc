"""The software rasterizer and figures: coverage, z-buffer, interpolation, shading, overlays
and the composed heatmap / correspondence images."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from litege_core.render.figures import (
    Overlay,
    colorbar,
    heatmap_figure,
    match_figure,
    parse_size,
    render_surface,
)
from litege_core.render.raster import (
    fit_camera,
    rasterize_mesh,
    rasterize_points,
    view_axes,
)


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_camera_fits_the_points_in_the_frame(sphere):
    vertices, _ = sphere
    camera = fit_camera(vertices, (200, 100), "front", margin=0.1)
    x, y, _ = camera.project(vertices)
    assert x.min() >= 0 and x.max() <= 200 and y.min() >= 0 and y.max() <= 100
    assert y.max() - y.min() == pytest.approx(80, abs=1.0)  # height-limited: 80 % of 100 px


def test_view_axes_are_orthonormal():
    for view in ("three_quarter", "side", "top", (1.0, 2.0, 3.0)):
        towards, up = view_axes(view)
        assert np.linalg.norm(towards) == pytest.approx(1)
        assert np.linalg.norm(up) == pytest.approx(1)
        assert towards @ up == pytest.approx(0, abs=1e-12)
    with pytest.raises(ValueError):
        view_axes("sideways")


def test_sphere_covers_a_disk_and_depth_is_nearest(sphere):
    vertices, faces = sphere
    camera = fit_camera(vertices, (120, 120), "front", margin=0.0)
    frags = rasterize_mesh(camera, vertices, faces)
    coverage = frags.mask.mean()
    assert coverage == pytest.approx(np.pi / 4, rel=0.03)  # a disk inscribed in the square
    # the centre pixel sees the front of the sphere (z = +1, towards the viewer)
    z = frags.interpolate(vertices[:, 2])
    assert z[60, 60] == pytest.approx(1.0, abs=0.02)
    assert np.isnan(z[0, 0])
    weights = frags.weights[frags.mask]
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-9)


def test_nearer_triangle_wins_whatever_the_order():
    square = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    near = square * [0.5, 0.5, 1] + [0, 0, 1]  # in front (towards +z, the viewer)
    vertices = np.vstack([square, near])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    camera = fit_camera(square, (40, 40), "front", margin=0.0)
    for order in (faces, faces[::-1]):
        frags = rasterize_mesh(camera, vertices, order)
        element = frags.element[20, 20]
        assert set(order[element]) <= {4, 5, 6, 7}
        assert set(order[frags.element[2, 2]]) <= {0, 1, 2, 3}


def test_point_splats_cover_and_shade(sphere):
    vertices, _ = sphere
    camera = fit_camera(vertices, (100, 100), "front")
    frags = rasterize_points(camera, vertices, 3.0)
    assert 0.3 < frags.mask.mean() < 0.8
    normals = frags.normals[frags.mask]
    assert np.all(np.linalg.norm(normals, axis=1) > 0.5)


def test_render_surface_scalar_field_goes_dark_to_bright(sphere):
    vertices, faces = sphere
    field = vertices[:, 0] + 1.0  # 0 on the left, 2 on the right
    image = np.asarray(
        render_surface(vertices, faces, scalar=field, size=(160, 160), view="front", ssaa=1)
    )
    assert image.shape == (160, 160, 3)
    row = image[80].astype(float)
    luma = row @ [0.2126, 0.7152, 0.0722]
    assert luma[45] < luma[115]  # left (low distance) darker than right (high) in viridis
    assert (image[0, 0] == 255).all()  # white background
    # isolines: dark pixels inside the disk
    inside = image[50:110, 50:110].reshape(-1, 3).astype(float) @ [0.2126, 0.7152, 0.0722]
    assert inside.min() < 40


def test_render_surface_cloud_colors_and_overlay(sphere):
    vertices, _ = sphere
    colors = np.tile([[1.0, 0.0, 0.0]], (len(vertices), 1))
    overlay = Overlay(
        paths=[(vertices[[0, 5, 10]], (0.0, 0.0, 1.0))], markers=[(vertices[0], (0, 1, 0))]
    )
    image = np.asarray(
        render_surface(vertices, None, colors=colors, overlay=overlay, size=(120, 90), ssaa=2)
    )
    assert image.shape == (90, 120, 3)
    reds = (image[..., 0] > 120) & (image[..., 1] < 60) & (image[..., 2] < 60)
    assert reds.mean() > 0.1


def test_heatmap_figure_has_colorbar_title_and_path(sphere):
    vertices, faces = sphere
    distances = np.linalg.norm(vertices - vertices[0], axis=1)
    figure = heatmap_figure(
        vertices,
        faces,
        distances,
        source_point=vertices[0],
        path=vertices[[0, 1, 2]],
        title="test",
        size=(200, 150),
        ssaa=1,
    )
    assert figure.size == (200 + 130, 150 + 26)
    pixels = np.asarray(figure).reshape(-1, 3)
    assert len(np.unique(pixels, axis=0)) > 50
    bar = np.asarray(colorbar(200, 0.0, 3.0, "distance"))
    assert bar.shape == (200, 96, 3)


def test_match_figure_is_side_by_side(sphere):
    vertices, faces = sphere
    colors = (vertices + 1) / 2
    figure = match_figure(
        vertices, faces, colors, vertices, None, colors, size=(100, 80), ssaa=1, title="m"
    )
    assert figure.width == 2 * 100 + 12
    assert figure.height == 80 + 26 + 26


def test_parse_size():
    assert parse_size("640x480") == (640, 480)
    for bad in ("640", "axb", "1x1", "100000x10"):
        with pytest.raises(ValueError):
            parse_size(bad)
