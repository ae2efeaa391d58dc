"""Tests of litege_core.matching.search: coarse-to-fine search against the exhaustive argmin."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from litege_core.errors import ArrayShapeError, InputError
from litege_core.matching import (
    DEFAULT_BEAMS,
    NNCache,
    coarse_to_fine_search,
    exhaustive_search,
    max_evaluations,
    resolve_beams,
)
from litege_core.matching.search import _distinct_rows
from litege_core.nets import matching_net
from litege_core.sampling import sample_surface


class CountingScore:
    """Wraps a score function; records the pairs of every call."""

    def __init__(self, fn) -> None:
        self.fn = fn
        self.calls: list[tuple[int, int]] = []

    def __call__(self, rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        assert rows.dtype == torch.int64 and cand.dtype == torch.int64
        assert cand.shape[0] == rows.shape[0]
        self.calls.append(tuple(cand.shape))
        return self.fn(rows, cand)

    @property
    def evaluations(self) -> int:
        return sum(m * c for m, c in self.calls)


def euclidean_score(queries: np.ndarray, points: np.ndarray):
    """Score ``‖x_q − y‖`` in float64: the argmin is the nearest point of Y to ``x_q``."""
    x = torch.as_tensor(queries, dtype=torch.float64)
    y = torch.as_tensor(points, dtype=torch.float64)

    def score(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return torch.linalg.vector_norm(x[rows][:, None, :] - y[cand], dim=-1)

    return score


def table_score(table: torch.Tensor):
    """Score looked up in a dense ``(Q, N)`` table (arbitrary, non-smooth scores)."""

    def score(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return table[rows[:, None], cand]

    return score


@pytest.fixture(scope="module")
def surfaces(blob) -> tuple[np.ndarray, np.ndarray]:
    """Target Y: 5000 samples of one bent ellipsoid; queries: 1000 samples of another one
    (a different member of the family, so queries lie off Y's surface)."""
    target = blob(0, subdivisions=4)
    source = blob(5, subdivisions=4)
    y = sample_surface(np.asarray(target.vertices), np.asarray(target.faces), 5000, 0).points
    x = sample_surface(np.asarray(source.vertices), np.asarray(source.faces), 1000, 1).points
    return x, y


def _agreement(cache: NNCache, score, n_queries: int, **kwargs) -> tuple[float, float, int]:
    counting = CountingScore(score)
    matches, distances = coarse_to_fine_search(cache, counting, n_queries, **kwargs)
    ex_matches, ex_distances = exhaustive_search(score, n_queries, cache.n_points)
    assert torch.all(distances >= ex_distances)  # the exhaustive minimum is a lower bound
    agree = float((matches == ex_matches).double().mean())
    return agree, float((distances - ex_distances).max()), counting.evaluations


# --------------------------------------------------------------------------- smooth scores


def test_matches_exhaustive_on_a_deformed_surface(surfaces) -> None:
    """Default FPS cache and beam: all 1000 queries agree with the exhaustive argmin, with
    5.4 % of its evaluations (beam 1, the reference's greedy descent: also 100 %, 3.7 %)."""
    x, y = surfaces
    cache = NNCache.build(y)
    score = euclidean_score(x, y)
    agree, excess, evaluations = _agreement(cache, score, 1000)
    assert agree >= 0.99
    assert excess < 0.01
    assert evaluations <= 1000 * max_evaluations(cache, DEFAULT_BEAMS)
    assert evaluations < 0.07 * 1000 * 5000
    greedy, _, greedy_evaluations = _agreement(cache, score, 1000, beams=1)
    assert greedy >= 0.98
    assert greedy_evaluations == 1000 * (60 + 65 + 60)


def test_matches_exhaustive_geodesic_on_a_sphere() -> None:
    """Great-circle distance between a rotated query and Y's points, 4000 random points on
    the unit sphere, 1000 queries: all agree with the exhaustive argmin."""
    rng = np.random.default_rng(0)
    y = rng.normal(size=(4000, 3))
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    x = rng.normal(size=(1000, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    rotated = torch.as_tensor(x @ Rotation.random(random_state=1).as_matrix().T)
    points = torch.as_tensor(y)

    def geodesic(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        chord = torch.linalg.vector_norm(rotated[rows][:, None, :] - points[cand], dim=-1)
        return 2.0 * torch.arcsin((chord / 2.0).clamp(max=1.0))  # accurate near 0

    cache = NNCache.build(y)
    agree, excess, evaluations = _agreement(cache, geodesic, 1000)
    assert agree >= 0.995
    assert excess < 1e-9 or agree >= 0.999
    assert evaluations < 0.1 * 1000 * 4000


def test_fps_tiers_beat_the_reference_random_tiers(surfaces) -> None:
    """Greedy descent (beam 1) on the same surface: FPS tiers agree at least as often as the
    reference's random tiers (measured: FPS 100 %, random seeds 0–2: 99.7–99.8 %)."""
    x, y = surfaces
    score = euclidean_score(x, y)
    fps, _, _ = _agreement(NNCache.build(y), score, 1000, beams=1)
    for seed in range(3):
        random, _, _ = _agreement(
            NNCache.build(y, strategy="random", seed=seed), score, 1000, beams=1
        )
        assert fps >= random
        assert random >= 0.9


def test_beam_recovers_greedy_misses_on_a_rough_score(surfaces) -> None:
    """A rough score (Euclidean plus a high-frequency perturbation of amplitude 0.2, a stand-in
    for network error) has local minima that trap a greedy descent. Measured agreement with
    the exhaustive argmin, FPS tiers: beam 1 99.6 %, beam 2 100 %; random tiers: beam 1
    98.0 %, beam 2 99.6 %."""
    x, y = surfaces
    rng = np.random.default_rng(3)
    freq = torch.as_tensor(rng.normal(size=(20, 3)) * 25.0)
    phase = torch.as_tensor(rng.uniform(0.0, 2.0 * np.pi, 20))
    bump = 0.2 * torch.sin(torch.as_tensor(y) @ freq.T + phase).mean(-1)  # (N,)
    base = euclidean_score(x, y)

    def rough(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return base(rows, cand) + bump[cand]

    fps = NNCache.build(y)
    random = NNCache.build(y, strategy="random")
    greedy, _, _ = _agreement(fps, rough, 1000, beams=1)
    beam, _, _ = _agreement(fps, rough, 1000, beams=2)
    random_greedy, _, _ = _agreement(random, rough, 1000, beams=1)
    random_beam, _, _ = _agreement(random, rough, 1000, beams=2)
    assert beam >= 0.995 and beam >= greedy
    assert random_beam > random_greedy
    assert greedy > random_greedy


# --------------------------------------------------------------------------- properties


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_points=st.integers(1, 90),
    n_queries=st.integers(1, 12),
    sizes=st.lists(st.integers(1, 80), min_size=1, max_size=3, unique=True),
    k=st.integers(1, 10),
    beams=st.integers(1, 4),
    strategy=st.sampled_from(["fps", "random"]),
)
def test_any_score_gives_valid_matches(
    seed: int,
    n_points: int,
    n_queries: int,
    sizes: list[int],
    k: int,
    beams: int,
    strategy: str,
) -> None:
    """For arbitrary (random) scores: valid indices, the returned distance is the score of the
    returned point, never below the exhaustive minimum, and the evaluation bound holds."""
    rng = np.random.default_rng(seed)
    cache = NNCache.build(
        rng.normal(size=(n_points, 3)),
        tier_sizes=sorted(sizes),
        neighbours=k,
        strategy=strategy,
        seed=seed,
    )
    table = torch.as_tensor(rng.random((n_queries, n_points)))
    counting = CountingScore(table_score(table))
    matches, distances = coarse_to_fine_search(cache, counting, n_queries, beams=beams)
    assert matches.shape == distances.shape == (n_queries,)
    assert matches.dtype == torch.int64
    assert int(matches.min()) >= 0 and int(matches.max()) < n_points
    torch.testing.assert_close(distances, table[torch.arange(n_queries), matches])
    assert torch.all(distances >= table.min(dim=1).values)
    assert counting.evaluations <= n_queries * max_evaluations(cache, beams)


@settings(max_examples=50, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_points=st.integers(1, 80),
    n_queries=st.integers(1, 10),
    sizes=st.lists(st.integers(1, 70), min_size=1, max_size=3, unique=True),
    beams=st.integers(1, 3),
    strategy=st.sampled_from(["fps", "random"]),
)
def test_full_neighbourhoods_are_exhaustive(
    seed: int,
    n_points: int,
    n_queries: int,
    sizes: list[int],
    beams: int,
    strategy: str,
) -> None:
    """With every link reaching the whole next tier the last tier scores all points, so the
    result equals the exhaustive argmin for any score."""
    rng = np.random.default_rng(seed)
    cache = NNCache.build(
        rng.normal(size=(n_points, 3)),
        tier_sizes=sorted(sizes),
        neighbours=n_points,
        strategy=strategy,
        seed=seed,
    )
    score = table_score(torch.as_tensor(rng.random((n_queries, n_points))))
    matches, distances = coarse_to_fine_search(cache, score, n_queries, beams=beams)
    ex_matches, ex_distances = exhaustive_search(score, n_queries, n_points)
    torch.testing.assert_close(matches, ex_matches)
    torch.testing.assert_close(distances, ex_distances)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_points=st.integers(2, 120),
    n_queries=st.integers(1, 15),
    max_pairs=st.integers(1, 60),
    beams=st.integers(1, 3),
)
def test_chunking_bounds_pairs_and_keeps_results(
    seed: int, n_points: int, n_queries: int, max_pairs: int, beams: int
) -> None:
    rng = np.random.default_rng(seed)
    cache = NNCache.build(rng.normal(size=(n_points, 3)), tier_sizes=(5, 30), neighbours=(8, 7))
    score = table_score(torch.as_tensor(rng.random((n_queries, n_points))))
    whole = coarse_to_fine_search(cache, score, n_queries, beams=beams)
    counting = CountingScore(score)
    chunked = coarse_to_fine_search(cache, counting, n_queries, beams=beams, max_pairs=max_pairs)
    assert all(m * c <= max_pairs for m, c in counting.calls)
    torch.testing.assert_close(chunked, whole)
    counting.calls.clear()
    ex = exhaustive_search(counting, n_queries, n_points, max_pairs=max_pairs)
    assert all(m * c <= max_pairs for m, c in counting.calls)
    torch.testing.assert_close(ex, exhaustive_search(score, n_queries, n_points))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.integers(0, 6), min_size=5, max_size=5), min_size=1, max_size=6))
def test_distinct_rows(rows: list[list[int]]) -> None:
    cand = torch.as_tensor(rows, dtype=torch.int64)
    compact, valid = _distinct_rows(cand)
    widths = [len(set(row)) for row in rows]
    assert compact.shape == (len(rows), max(widths))
    mask = torch.ones_like(compact, dtype=torch.bool) if valid is None else valid
    for row, out, keep, width in zip(rows, compact.tolist(), mask.tolist(), widths, strict=True):
        assert sum(keep) == width
        kept = [v for v, flag in zip(out, keep, strict=True) if flag]
        assert sorted(kept) == sorted(set(row))
        assert set(out) <= set(row)  # padding is a real candidate
    assert (valid is None) == (len(set(widths)) == 1)


def test_beam_search_scores_each_point_once(surfaces) -> None:
    """Overlapping neighbourhoods are deduplicated: per query and tier no point is scored
    twice apart from masked padding, which repeats one of the row's candidates."""
    x, y = surfaces
    cache = NNCache.build(y)
    seen: list[torch.Tensor] = []
    base = euclidean_score(x[:50], y)

    def recording(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        seen.append(cand.clone())
        return base(rows, cand)

    coarse_to_fine_search(cache, recording, 50, beams=4)
    for cand in seen[1:]:
        for row in cand.tolist():
            counts = sorted((row.count(v) for v in set(row)), reverse=True)
            assert counts[1:] == [1] * (len(counts) - 1)


# --------------------------------------------------------------------------- edge cases


def test_single_tier_cache_is_exhaustive() -> None:
    rng = np.random.default_rng(0)
    cache = NNCache.build(rng.normal(size=(40, 3)))
    assert cache.n_tiers == 1
    score = table_score(torch.as_tensor(rng.random((7, 40))))
    torch.testing.assert_close(
        coarse_to_fine_search(cache, score, 7), exhaustive_search(score, 7, 40)
    )
    assert max_evaluations(cache) == 40


def test_the_search_returns_candidates_only() -> None:
    """Points left out of ``candidates`` (a scan's strays) are never scored nor returned, even
    where they score best, with tiers or with one tier of candidates; among the candidates a
    cache without tiers is exhaustive."""
    rng = np.random.default_rng(2)
    for n_points in (40, 3000):
        points = rng.normal(size=(n_points, 3))
        excluded = rng.choice(n_points, n_points // 10, replace=False)
        table = torch.as_tensor(rng.random((9, n_points)))
        table[:, excluded] = -1.0  # the best score of all
        candidates = np.setdiff1d(np.arange(n_points), excluded)
        cache = NNCache.build(points, candidates=candidates)
        scored: list[np.ndarray] = []
        lookup = table_score(table)

        def score(
            rows: torch.Tensor, cand: torch.Tensor, scored=scored, lookup=lookup
        ) -> torch.Tensor:
            scored.append(cand.numpy().ravel())
            return lookup(rows, cand)

        matches, _ = coarse_to_fine_search(cache, score, 9)
        assert not np.isin(matches.numpy(), excluded).any()
        assert not np.isin(np.concatenate(scored), excluded).any()
        if n_points == 40:  # one tier of every candidate: exhaustive over them
            assert cache.tier_sizes == (36, 40)
            best = candidates[table[:, candidates].argmin(dim=1).numpy()]
            np.testing.assert_array_equal(matches.numpy(), best)


def test_no_queries() -> None:
    cache = NNCache.build(np.random.default_rng(0).normal(size=(100, 3)))

    def never(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        raise AssertionError("not called")

    matches, distances = coarse_to_fine_search(cache, never, 0)
    assert matches.shape == distances.shape == (0,)
    assert matches.dtype == torch.int64
    assert exhaustive_search(never, 0, 100)[0].shape == (0,)


def test_nan_scores_count_as_infinite() -> None:
    rng = np.random.default_rng(1)
    table = torch.as_tensor(rng.random((5, 100)))
    table[:, ::2] = float("nan")
    cache = NNCache.build(rng.normal(size=(100, 3)), tier_sizes=(10,), neighbours=100)
    matches, distances = coarse_to_fine_search(cache, table_score(table), 5)
    assert torch.all(matches % 2 == 1)
    assert torch.isfinite(distances).all()
    all_nan = torch.full((2, 100), float("nan"))
    _, distances = coarse_to_fine_search(cache, table_score(all_nan), 2)
    assert torch.isinf(distances).all()


@pytest.mark.parametrize(
    "bad",
    [
        lambda rows, cand: torch.zeros(cand.shape[0]),
        lambda rows, cand: torch.zeros(cand.shape[0], cand.shape[1] + 1),
        lambda rows, cand: np.zeros(tuple(cand.shape)),
    ],
)
def test_score_fn_shape_is_checked(bad) -> None:
    cache = NNCache.build(np.random.default_rng(0).normal(size=(100, 3)))
    with pytest.raises(ArrayShapeError):
        coarse_to_fine_search(cache, bad, 3)
    with pytest.raises(ArrayShapeError):
        exhaustive_search(bad, 3, 100)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"beams": 0},
        {"beams": ()},
        {"beams": (2, True)},
        {"max_pairs": 0},
        {"max_pairs": 2.5},
        {"n_queries": -1},
        {"n_queries": 1.0},
    ],
)
def test_rejects_bad_arguments(kwargs: dict) -> None:
    cache = NNCache.build(np.random.default_rng(0).normal(size=(100, 3)))
    score = table_score(torch.zeros(3, 100))
    arguments = {"n_queries": 3, **kwargs}
    n_queries = arguments.pop("n_queries")
    with pytest.raises(InputError):
        coarse_to_fine_search(cache, score, n_queries, **arguments)


def test_exhaustive_rejects_empty_target() -> None:
    with pytest.raises(InputError):
        exhaustive_search(table_score(torch.zeros(1, 1)), 1, 0)


def test_resolve_beams() -> None:
    assert resolve_beams(3, 3) == (3, 3)
    assert resolve_beams((4, 2), 3) == (4, 2)
    assert resolve_beams((4,), 4) == (4, 4, 4)
    assert resolve_beams((4, 2, 1), 2) == (4,)
    assert resolve_beams(2, 1) == ()


# --------------------------------------------------------------------------- real network


def test_drives_the_matching_network_head() -> None:
    """The intended use: embed X's queries and all of Y's points once, run only the head per
    pair. With full neighbourhoods the (untrained) network's argmin is found exactly."""
    torch.manual_seed(0)
    net = matching_net().eval()
    rng = np.random.default_rng(0)
    y = torch.as_tensor(rng.normal(size=(150, 3)), dtype=torch.float32)
    x = torch.as_tensor(rng.normal(size=(6, 3)), dtype=torch.float32)
    z = torch.as_tensor(rng.normal(size=(2, 400)), dtype=torch.float32)
    with torch.no_grad():
        shape_x, shape_y = net.shape_embedding(z)
        e_x = net.point_embedding(x, shape_x)  # (6, n)
        e_y = net.point_embedding(y, shape_y)  # (150, n)

    def score(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return net.head(e_x[rows][:, None, :], e_y[cand])

    cache = NNCache.build(y.double().numpy(), tier_sizes=(10, 40), neighbours=150)
    matches, distances = coarse_to_fine_search(cache, score, 6, beams=1)
    ex_matches, ex_distances = exhaustive_search(score, 6, 150)
    torch.testing.assert_close(matches, ex_matches)
    torch.testing.assert_close(distances, ex_distances)
    with torch.no_grad():
        direct = net(x, y[matches], z[:1].expand(6, -1), z[1:].expand(6, -1))
    torch.testing.assert_close(distances, direct, rtol=1e-4, atol=1e-5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_runs_on_cuda(surfaces) -> None:
    x, y = surfaces
    cache = NNCache.build(y)
    xs = torch.as_tensor(x, device="cuda")
    ys = torch.as_tensor(y, device="cuda")

    def score(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return torch.linalg.vector_norm(xs[rows][:, None, :] - ys[cand], dim=-1)

    matches, distances = coarse_to_fine_search(cache, score, 1000, device="cuda")
    assert matches.device.type == "cuda" and distances.device.type == "cuda"
    cpu_matches, _ = coarse_to_fine_search(cache, euclidean_score(x, y), 1000)
    torch.testing.assert_close(matches.cpu(), cpu_matches)
