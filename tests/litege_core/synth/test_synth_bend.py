"""Body bends (litege_core.synth.bend): a curve deformer along the forward axis."""

import numpy as np
import pytest

from litege_core.errors import InputError
from litege_core.synth.bend import (
    Bend,
    BendSettings,
    bend_body,
    body_axes,
    bump,
    draw_bend,
    random_bend,
)


def rod(n: int = 401, length: float = 2.0) -> np.ndarray:
    """Points on the forward axis (body coordinates ``(s, l, u)``)."""
    return np.stack([np.linspace(0.0, length, n), np.zeros(n), np.zeros(n)], axis=1)


def test_no_bend_is_the_identity():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(200, 3))
    flat = Bend(0.0, 0.0, 0.5, 0.3, 0.5, 0.3)
    np.testing.assert_allclose(bend_body(points, flat), points, atol=1e-12)


def test_bump_integrates_to_one_over_the_body():
    s = np.linspace(-1.0, 3.0, 4001)
    assert np.trapezoid(bump(s, -1.0, 4.0, 0.3, 0.1), s) == pytest.approx(1.0, rel=1e-4)


@pytest.mark.parametrize(("lateral", "vertical"), [(np.pi / 2, 0.0), (0.0, -0.6), (1.2, 0.5)])
def test_the_centre_line_keeps_its_length_and_turns_by_the_total_angle(lateral, vertical):
    points = rod()
    bent = bend_body(points, Bend(lateral, vertical, 0.5, 0.2, 0.5, 0.2))
    steps = np.linalg.norm(np.diff(bent, axis=0), axis=1)
    np.testing.assert_allclose(steps, np.diff(points[:, 0]), rtol=1e-3)
    start = bent[1] - bent[0]
    end = bent[-1] - bent[-2]
    turn = np.arccos(np.clip(start @ end / np.linalg.norm(start) / np.linalg.norm(end), -1, 1))
    # the bump's tails outside the body are cut: the turn is the share of Θ inside it
    grid = np.linspace(0.0, 2.0, 4001)
    inside = np.trapezoid(bump(grid, 0.0, 2.0, 0.5, 0.2), grid)
    assert inside == pytest.approx(1.0, abs=1e-3)
    assert turn == pytest.approx(np.hypot(lateral, vertical), abs=2e-3)


def test_the_body_centre_keeps_its_place_and_heading():
    points = rod(801, 2.0) - np.array([1.0, 0.0, 0.0])  # s in [-1, 1], centre sample at 0
    bent = bend_body(points, Bend(1.3, -0.4, 0.35, 0.2, 0.7, 0.25))
    np.testing.assert_allclose(bent[400], points[400], atol=1e-9)
    tangent = bent[401] - bent[399]
    np.testing.assert_allclose(tangent / np.linalg.norm(tangent), [1.0, 0.0, 0.0], atol=1e-3)


def test_a_lateral_bend_stays_in_the_horizontal_plane_and_keeps_offsets():
    rng = np.random.default_rng(1)
    s = rng.uniform(0.0, 2.0, 500)
    offsets = rng.uniform(-0.1, 0.1, (500, 2))
    points = np.column_stack([s, offsets])
    bend = Bend(1.5, 0.0, 0.5, 0.25, 0.5, 0.25)
    bent = bend_body(points, bend)
    np.testing.assert_allclose(bent[:, 2], points[:, 2], atol=1e-9)  # heights kept
    centres = bend_body(np.column_stack([s, np.zeros((500, 2))]), bend)
    np.testing.assert_allclose(
        np.linalg.norm(bent - centres, axis=1), np.linalg.norm(offsets, axis=1), rtol=1e-4
    )


def test_draw_bend_draws_nothing_when_disabled():
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    assert draw_bend(rng, rod(), BendSettings()) is None
    assert rng.bit_generator.state == state
    vertices = rod()
    same, bend = random_bend(rng, vertices, np.eye(3), BendSettings())
    assert bend is None and same is vertices


def test_drawn_bends_respect_the_compression_cap():
    rng = np.random.default_rng(4)
    body = np.column_stack(
        [rng.uniform(-1.0, 1.0, 2000), rng.uniform(-0.3, 0.3, 2000), rng.uniform(-0.6, 0.4, 2000)]
    )
    settings = BendSettings(probability=1.0, lateral_degrees=180.0, vertical_degrees=90.0)
    length = np.ptp(body[:, 0])
    for _ in range(50):
        bend = draw_bend(rng, body, settings)
        assert bend is not None
        for turn, width, column in (
            (bend.lateral, bend.lateral_width, 1),
            (bend.vertical, bend.vertical_width, 2),
        ):
            peak = abs(turn) / (np.sqrt(2 * np.pi) * width * length)
            assert peak * np.abs(body[:, column]).max() <= settings.max_compression + 1e-9
            assert abs(turn) <= np.radians(180.0)
            assert settings.width_range[0] <= width <= settings.width_range[1]


def test_probability_selects_a_share_of_shapes():
    settings = BendSettings(probability=0.3)
    bent = sum(
        draw_bend(np.random.default_rng(seed), rod(), settings) is not None for seed in range(400)
    )
    assert 80 < bent < 160


def test_body_axes_take_the_longer_horizontal_extent_as_forward():
    rng = np.random.default_rng(5)
    box = rng.uniform(-1.0, 1.0, (500, 3)) * np.array([0.3, 0.5, 1.5])
    axes = body_axes(box)
    np.testing.assert_array_equal(axes[0], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(axes[2], [0.0, 1.0, 0.0])
    assert np.linalg.det(axes) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"probability": 1.5},
        {"lateral_degrees": -1.0},
        {"width_range": (0.0, 0.2)},
        {"width_range": (0.3, 0.2)},
        {"max_compression": 1.0},
    ],
)
def test_bad_settings_are_input_errors(kwargs):
    with pytest.raises(InputError):
        BendSettings(**kwargs)


def test_describe_names_every_setting():
    text = BendSettings(probability=0.7).describe()
    assert text == "bend(p=0.7,lat=140,vert=40,w=0.12-0.45,c=0.6,anchor=centre)"
    assert BendSettings().describe() != text
