"""Fitting the graph-fusion calibration (``litege_core.evaluation.fusion``) on samples whose
best blend is known: the bias knots recover the graph's over-estimate and the gate learns to
trust the graph on unusual shapes and the network on familiar ones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from litege_core.evaluation.fusion import (
    FusionSample,
    choose_mesh_cloud_noise,
    choose_normal_limits,
    fit_fusion,
    fusion_summary,
    fusion_table,
    is_clean_mesh,
    mesh_noise_knots,
    sample_error,
    with_cloud_rows,
)
from litege_core.evaluation.geodesic import make_input


def _samples() -> list[FusionSample]:
    """Familiar shapes (z = 0): the network is nearly exact, the graph noisy. Unusual shapes
    (z = 4): the network is off by a shape-wide factor, the graph exact up to its bias 1.05
    (at 1000 points) or 1.10 (at 300 points). Meshes: the network is noisy, the mesh-edge graph
    exact up to its bias 1.06."""
    rng = np.random.default_rng(0)
    samples = []
    for i in range(6):
        truth = rng.uniform(10.0, 200.0, size=(4, 50))
        network = truth * rng.normal(1.0, 0.1, truth.shape)
        graph = truth * 1.06 * rng.normal(1.0, 0.005, truth.shape)
        samples.append(
            FusionSample(f"m{i}", "toy", "mesh", True, 800, 0.0, 0.1, network, graph, truth)
        )
    for setting, n_points, bias in (("cloud_1000", 1000, 1.05), ("cloud_300", 300, 1.10)):
        for i in range(12):
            truth = rng.uniform(10.0, 200.0, size=(4, 50))
            truth[:, 0] = 0.0
            unusual = i % 2 == 1
            if unusual:
                network = truth * rng.choice([0.7, 1.3])
                graph = truth * bias * rng.normal(1.0, 0.01, truth.shape)
            else:
                network = truth * rng.normal(1.0, 0.01, truth.shape)
                graph = truth * bias * rng.normal(1.0, 0.3, truth.shape)
            z_score = 4.0 if unusual else 0.0
            samples.append(
                FusionSample(
                    f"s{i}", "toy", setting, False, n_points, z_score, 0.1, network, graph, truth
                )
            )
    return samples


def test_the_fit_recovers_the_bias_and_picks_the_better_input_per_shape() -> None:
    samples = _samples()
    calibration = fit_fusion(samples, "h" * 64, k=8, prune_ratio=1.5, fitted_on={"n": 24})
    assert (calibration.k, calibration.prune_ratio, calibration.fitted_on) == (8, 1.5, {"n": 24})
    assert calibration.bias_log10_points == pytest.approx((np.log10(300), 3.0))
    assert calibration.bias == pytest.approx((1.10, 1.05), abs=0.01)
    assert calibration.network_weight(0.0, 1000, 0.1) > 0.8
    assert calibration.network_weight(4.0, 1000, 0.1) < 0.2
    assert calibration.mesh_bias == pytest.approx(1.06, abs=0.005)
    assert calibration.network_weight(0.0, 800, 0.1, mesh=True) == 0.0  # the graph alone
    fused = np.mean([sample_error(s, calibration, "fused") for s in samples])
    network = np.mean([sample_error(s, None, "network") for s in samples])
    graph = np.mean([sample_error(s, None, "graph") for s in samples])
    assert fused < 0.5 * min(network, graph)
    summary = fusion_summary(samples, calibration)
    assert [(r["setting"], r["shapes"]) for r in summary] == [
        ("mesh", 6),
        ("cloud_1000", 12),
        ("cloud_300", 12),
    ]
    assert all(r["fused"] < r["network"] for r in summary)
    table = fusion_table(summary, calibration.k)
    assert "| toy | cloud_1000 | 12 |" in table and "| toy | mesh | 6 |" in table


def test_without_mesh_samples_a_mesh_graph_keeps_its_lengths() -> None:
    clouds = [s for s in _samples() if not s.mesh]
    calibration = fit_fusion(clouds, "h" * 64, k=8, prune_ratio=1.5)
    assert calibration.mesh_bias == 1.0
    assert calibration.network_weight(0.0, 800, 0.1, mesh=True) == 0.0


def test_noisy_meshes_give_the_mesh_bias_its_noise_knots() -> None:
    """Clean meshes (noise ~0.02) fix ``mesh_bias``; each noisy-mesh setting adds a knot at its
    median noise with its median bias, so a noisy mesh is answered with its own bias; a
    setting no noisier than the clean meshes adds none."""
    rng = np.random.default_rng(1)
    clean = [s for s in _samples() if s.mesh]
    samples = [dataclasses.replace(s, roughness=0.02) for s in clean]
    for setting, noise, bias in (("meshnoise_0.002", 0.1, 1.08), ("meshnoise_0.004", 0.2, 1.15)):
        for i in range(6):
            truth = rng.uniform(10.0, 200.0, size=(4, 50))
            graph = truth * bias * rng.normal(1.0, 0.005, truth.shape)
            samples.append(
                FusionSample(f"n{i}", "toy", setting, True, 800, 0.0, noise, truth, graph, truth)
            )
    clouds = [s for s in _samples() if not s.mesh]
    calibration = fit_fusion(samples + clouds, "h" * 64, k=8, prune_ratio=1.5)
    assert calibration.mesh_bias == pytest.approx(1.06, abs=0.005)  # the clean meshes only
    assert calibration.mesh_noise_knots == pytest.approx((0.02, 0.1, 0.2))
    assert calibration.mesh_noise_bias == pytest.approx((1.06, 1.08, 1.15), abs=0.005)
    noisy = [s for s in samples if s.setting != "mesh"]
    constant = dataclasses.replace(calibration, mesh_noise_knots=(), mesh_noise_bias=())
    fused = np.mean([sample_error(s, calibration, "fused") for s in noisy])
    assert fused < 0.5 * np.mean([sample_error(s, constant, "fused") for s in noisy])
    assert mesh_noise_knots(clean) == ((), ())  # one setting: a constant bias
    # coarser clean meshes (any resolution) join the clean knot, at the clean meshes' 90 %
    coarse = [dataclasses.replace(s, setting="decimated_1000", roughness=0.04) for s in clean]
    knots, biases = mesh_noise_knots(samples[:6] + coarse + samples[6:])
    assert knots == pytest.approx((0.04, 0.1, 0.2)) and biases[0] == pytest.approx(1.06, abs=0.005)
    assert is_clean_mesh(coarse[0]) and not is_clean_mesh(samples[-1])
    as_clean = [dataclasses.replace(s, roughness=0.02) for s in samples if s.setting != "mesh"]
    assert mesh_noise_knots(samples[:6] + as_clean[:6]) == ((), ())  # no noisier than clean


def test_unreachable_graph_pairs_count_with_the_network_value() -> None:
    truth = np.array([[0.0, 10.0, 20.0]])
    sample = FusionSample(
        "s",
        "toy",
        "cloud_300",
        False,
        300,
        0.0,
        0.1,
        truth * 1.1,
        np.array([[0.0, 10.0, np.inf]]),
        truth,
    )
    # pairs with truth > 0: |10 - 10| and |22 - 20| (the network's value), GT mean 15
    assert sample_error(sample, None, "graph") == pytest.approx(np.mean([0.0, 2.0]) * 100 / 15)
    assert sample_error(sample, None, "network") == pytest.approx(np.mean([1.0, 2.0]) * 100 / 15)


def _blob_shapes(blob) -> list:
    """One calibration shape: a unit-area blob with exact rows from 4 FPS sources."""
    from litege_core.engines import compute_distances
    from litege_core.evaluation.geodesic import EvalShape, unit_area
    from litege_core.sampling import farthest_point_sampling
    from litege_core.shape import Shape

    shape = blob(7, subdivisions=3)
    vertices, _ = unit_area(shape.vertices, shape.faces)
    sources = farthest_point_sampling(vertices, 4)
    gt = compute_distances(Shape.from_arrays(vertices, shape.faces), sources, "exact").distances
    return [EvalShape("blob", "toy", vertices, np.asarray(shape.faces), sources, gt)]


def test_samples_share_the_network_rows_across_veto_thresholds(
    blob, toy_bundle_dir_with_ood
) -> None:
    from litege_core.evaluation.fusion import collect_samples
    from litege_core.learned import Predictor, load_bundle

    shapes = _blob_shapes(blob)
    predictor = Predictor(load_bundle(toy_bundle_dir_with_ood))
    by_variant = collect_samples(
        predictor,
        shapes,
        ("mesh", "cloud_300"),
        k=8,
        prune_ratios=(3.0, 1e9),  # untrained: 3 × chord cuts some edges
        normal_limits=(0.3, 1.0),
        mutual_ks=(0, 8),
    )
    assert sorted(by_variant) == [
        (ratio, limit, mutual) for ratio in (3.0, 1e9) for limit in (0.3, 1.0) for mutual in (0, 8)
    ]
    strict, loose = by_variant[(3.0, 1.0, 0)], by_variant[(1e9, 1.0, 0)]
    assert [(s.setting, s.mesh) for s in strict] == [("mesh", True), ("cloud_300", False)]
    for a, b in zip(strict, loose, strict=True):
        np.testing.assert_array_equal(a.network, b.network)
        np.testing.assert_array_equal(a.truth, b.truth)
    # a mesh's graph ignores the veto; a cloud's loses edges to it, so its paths only lengthen
    # (pairs it no longer joins read the network's value)
    np.testing.assert_array_equal(strict[0].graph, loose[0].graph)
    joined = strict[1].graph != strict[1].network
    assert joined.mean() > 0.5
    assert np.all(strict[1].graph[joined] >= loose[1].graph[joined] - 1e-9)
    assert np.any(strict[1].graph[joined] > loose[1].graph[joined] + 1e-6)

    # the mutual k-NN graph is a subgraph of the symmetric one: a cloud's paths lengthen,
    # a mesh's stay
    mutual = by_variant[(1e9, 1.0, 8)]
    np.testing.assert_array_equal(mutual[0].graph, loose[0].graph)
    joined = mutual[1].graph != mutual[1].network
    assert np.all(mutual[1].graph[joined] >= loose[1].graph[joined] - 1e-9)
    assert np.any(mutual[1].graph[joined] > loose[1].graph[joined] + 1e-6)

    # the normal limit only cuts edges too: a cloud's paths lengthen, a mesh's stay
    normal = by_variant[(1e9, 0.3, 0)]
    np.testing.assert_array_equal(normal[0].graph, loose[0].graph)
    joined = normal[1].graph != normal[1].network
    assert np.all(normal[1].graph[joined] >= loose[1].graph[joined] - 1e-9)
    assert np.any(normal[1].graph[joined] > loose[1].graph[joined] + 1e-6)


def test_samples_of_smoothed_meshes_read_the_smoothed_noise(blob, toy_bundle_dir_with_ood) -> None:
    """With a smoothing limit a noisy mesh's sample reads the denoised mesh's graph and the noise
    of the mesh as given (what the fitted bias reads); a clean mesh's is the same as without
    the limit."""
    from litege_core.evaluation.fusion import collect_samples
    from litege_core.learned import Predictor, load_bundle
    from litege_core.learned.mesh_noise import mesh_noise

    shapes = _blob_shapes(blob)
    predictor = Predictor(load_bundle(toy_bundle_dir_with_ood))
    settings = ("mesh", "meshnoise_0.02")
    plain, smoothed = (
        next(iter(collect_samples(predictor, shapes, settings, mesh_smooth_noise=s).values()))
        for s in (None, 0.08)
    )
    np.testing.assert_array_equal(plain[0].graph, smoothed[0].graph)
    assert [s.roughness for s in plain] == [s.roughness for s in smoothed]
    assert plain[0].roughness <= 0.08 < plain[1].roughness
    noisy = make_input(shapes[0], "meshnoise_0.02", 0).shape
    assert plain[1].roughness == pytest.approx(
        mesh_noise(predictor.register(noisy).canonical_points, np.asarray(noisy.faces))
    )
    far = plain[1].truth > 0
    ratios = [np.median(s.graph[far] / s.truth[far]) for s in (smoothed[1], plain[1])]
    assert 1.0 < ratios[0] < ratios[1]  # the smoothed mesh's paths zig-zag less


def _limit_samples(limit: float, rng_seed: int = 0) -> list[FusionSample]:
    """Samples as one normal limit would give them: at 2000 points the limit 0.7 cuts the
    shortcuts that leave the graph 10 % short, at 300 points it cuts surface edges (+15 %);
    a 2000-point noisy cloud follows the 2000-point clean one; a mesh ignores the limit."""
    rng = np.random.default_rng(rng_seed)
    cut = limit < 1.0
    samples = []
    for setting, n_points, factor in (
        ("mesh", 900, 1.0),
        ("cloud_2000", 2000, 1.0 if cut else 0.9),
        ("cloud_300", 300, 1.15 if cut else 1.0),
        ("noise_0.01", 2000, 1.0 if cut else 0.9),
    ):
        for i in range(4):
            truth = rng.uniform(10.0, 200.0, size=(3, 40))
            graph = truth * factor * rng.normal(1.0, 0.02 * (1 + (i % 2)), truth.shape)
            graph[:, : (i % 2) * 20] *= 0.8 if factor != 1.0 else 1.0  # the bias is uneven
            network = truth * rng.normal(1.0, 0.1, truth.shape)
            samples.append(
                FusionSample(
                    f"s{i}",
                    "toy",
                    setting,
                    setting == "mesh",
                    n_points,
                    0.0,
                    0.1,
                    network,
                    graph,
                    truth,
                )
            )
    return samples


def test_each_density_keeps_the_normal_limit_whose_graph_errs_least() -> None:
    by_limit = {limit: _limit_samples(limit) for limit in (0.7, 1.0)}
    chosen, merged = choose_normal_limits(by_limit)
    assert chosen == {"cloud_2000": 0.7, "cloud_300": 1.0}
    settings = [s.setting for s in merged]
    assert settings == [s.setting for s in by_limit[1.0]]
    for sample, plain, cut in zip(merged, by_limit[1.0], by_limit[0.7], strict=True):
        expected = cut if sample.setting in ("cloud_2000", "noise_0.01") else plain
        assert sample is expected
    calibration = fit_fusion(merged, "h" * 64, k=8, prune_ratio=1.5, normal_cos=chosen)
    assert calibration.bias_log10_points == pytest.approx((np.log10(300), np.log10(2000)))
    assert calibration.normal_cos == (1.0, 0.7)
    assert calibration.normal_limit(2000) == pytest.approx(0.7)
    assert fit_fusion(merged, "h" * 64, k=8, prune_ratio=1.5).normal_cos == ()


def _veto_samples() -> list[FusionSample]:
    """Clouds whose vetoed graph is right on familiar shapes (z = 0; six) and off by 30 % on
    unusual ones (z = 8; two), where the graph without the veto is right; the network is off
    by 20 % everywhere. "Right": within 5 % noise."""
    rng = np.random.default_rng(1)
    samples = []
    for i in range(8):
        truth = rng.uniform(10.0, 200.0, size=(3, 40))
        unusual = i % 4 == 3
        noisy = truth * rng.normal(1.0, 0.05, truth.shape)
        vetoed = truth * 1.3 if unusual else noisy
        unvetoed = noisy if unusual else truth * 1.3
        samples.append(
            FusionSample(
                f"s{i}",
                "toy",
                "cloud_1000",
                False,
                1000,
                8.0 if unusual else 0.0,
                0.1,
                truth * 1.2,
                vetoed,
                truth,
                unvetoed,
            )
        )
    return samples


def test_the_veto_limit_separates_familiar_from_unusual_shapes() -> None:
    from litege_core.evaluation.fusion import choose_veto_limit, with_veto_limit

    samples = _veto_samples()
    # the gate is fitted on the familiar shapes alone (as calibrate_fusion.py fits it on the
    # shapes of the model's kind); the unusual ones only choose the limit
    familiar = [s for s in samples if s.z_score == 0.0]
    calibration = fit_fusion(familiar, "h" * 64, k=8, prune_ratio=1.3)
    assert calibration.veto_max_z is None
    chosen, read, tried = choose_veto_limit(samples, calibration)
    # every limit from 1 to 6 keeps the veto on the familiar shapes only: the largest is kept
    assert chosen.veto_max_z == 6.0 and list(tried) == [None, 8.0, 6.0, 4.0, 3.0, 2.0, 1.0]
    assert tried[6.0] < tried[8.0] == pytest.approx(tried[None])
    assert chosen.gate == calibration.gate
    for sample, seen in zip(samples, read, strict=True):
        expected = sample.unvetoed if sample.z_score > 6.0 else sample.graph
        np.testing.assert_array_equal(seen.graph, expected)
    assert read == with_veto_limit(samples, chosen)
    # the floor: no limit below the highest z-score the veto must keep serving
    floored, _, tried = choose_veto_limit(samples, calibration, floor=5.0)
    assert floored.veto_max_z == 6.0 and list(tried) == [None, 8.0, 6.0]
    floored, _, tried = choose_veto_limit(samples, calibration, floor=7.0)
    assert floored.veto_max_z is None and list(tried) == [None, 8.0]  # 8 cuts no more
    # a shape at z = 5 that reads better without the veto moves the limit to 4 only if the
    # calibration's mean error falls by more than the tolerance
    for excess, expected in ((0.002, 6.0), (0.5, 4.0)):
        truth = samples[0].truth
        middle = dataclasses.replace(
            samples[0], z_score=5.0, graph=truth * (1 + excess), unvetoed=truth
        )
        assert choose_veto_limit([*samples, middle], calibration)[0].veto_max_z == expected
    # familiar shapes alone, or no unvetoed rows: no limit, nothing changed
    assert choose_veto_limit(familiar, calibration)[0].veto_max_z is None
    plain = [dataclasses.replace(s, unvetoed=None) for s in samples]
    assert choose_veto_limit(plain, calibration) == (calibration, plain, {})


def _gate_samples(z_score: float, network_factor: float, graph_noise: float, seed: int):
    """Six clouds at ``z_score`` whose network is off by ``network_factor`` (± 1 % noise) and
    whose graph is right up to ``graph_noise``."""
    rng = np.random.default_rng(seed)
    samples = []
    for i in range(6):
        truth = rng.uniform(10.0, 200.0, size=(3, 40))
        network = truth * network_factor * rng.normal(1.0, 0.01, truth.shape)
        graph = truth * rng.normal(1.0, graph_noise, truth.shape)
        samples.append(
            FusionSample(
                f"z{z_score}-{i}",
                "toy",
                "cloud_1000",
                False,
                1000,
                z_score,
                0.1 * (i % 3),
                network,
                graph,
                truth,
            )
        )
    return samples


def test_the_gate_refit_for_unusual_shapes_keeps_the_familiar_ones_within_tolerance() -> None:
    from litege_core.evaluation.fusion import fit_gate_with_ood, mean_fused_error

    # familiar shapes (z 0 and 1): the network is right, the graph noisy; the in-kind fit
    # never sees a high z, so it trusts the network on the unusual shapes (z = 8) too, where
    # the network is 30 % off and the graph right
    familiar = _gate_samples(0.0, 1.0, 0.2, 0) + _gate_samples(1.0, 1.0, 0.2, 1)
    unusual = _gate_samples(8.0, 1.3, 0.02, 2)
    calibration = fit_fusion(familiar, "h" * 64, k=8, prune_ratio=1.3)
    assert calibration.network_weight(8.0, 1000, 0.1) > 0.5
    refit = dataclasses.replace(
        calibration, gate=fit_gate_with_ood(familiar, unusual, calibration, 0.01)
    )
    assert refit.network_weight(8.0, 1000, 0.1) < 0.2
    assert mean_fused_error(unusual, refit) < 0.5 * mean_fused_error(unusual, calibration)
    bound = mean_fused_error(familiar, calibration) * 1.01
    assert mean_fused_error(familiar, refit) <= bound
    # unusual shapes the gate cannot tell from familiar ones (same z and roughness): the
    # bound binds, and the familiar shapes keep nearly all the network's weight
    lookalikes = [dataclasses.replace(s, z_score=0.0) for s in unusual]
    bound_refit = dataclasses.replace(
        calibration, gate=fit_gate_with_ood(familiar, lookalikes, calibration, 0.01)
    )
    assert mean_fused_error(familiar, bound_refit) <= bound
    assert bound_refit.network_weight(0.0, 1000, 0.1) > 0.9
    # no unusual clouds: the gate as it was
    assert fit_gate_with_ood(familiar, [], calibration, 0.01) == calibration.gate


def test_ood_samples_read_the_fitted_graph_with_and_without_its_veto(
    blob, toy_bundle_dir_with_ood
) -> None:
    from litege_core.evaluation.fusion import collect_ood_samples, probe_calibration
    from litege_core.learned import Predictor, load_bundle

    shapes = _blob_shapes(blob)
    bundle = load_bundle(toy_bundle_dir_with_ood)
    predictor = Predictor(bundle)
    fitted = dataclasses.replace(  # untrained: 3 × chord cuts some edges
        probe_calibration(bundle.content_hash, 8, 3.0), bias=(1.2,), gate=(0.0, 0.0, 0.0, 0.0)
    )
    mesh, cloud = collect_ood_samples(predictor, shapes, fitted, ("mesh", "cloud_300"))
    assert mesh.unvetoed is None and cloud.unvetoed is not None
    # the raw graph (no bias, no blend): the veto only cuts edges, so paths only lengthen
    joined = (cloud.graph != cloud.network) & np.isfinite(cloud.unvetoed)
    assert joined.mean() > 0.5
    assert np.all(cloud.graph[joined] >= cloud.unvetoed[joined] - 1e-9)
    assert np.any(cloud.graph[joined] > cloud.unvetoed[joined] + 1e-6)


def test_noisy_meshes_are_read_again_as_clouds_of_their_vertices(
    blob, toy_bundle_dir_with_ood
) -> None:
    """``with_cloud_rows`` answers each noisy mesh's vertices as a cloud with the fitted fusion
    (the clean mesh keeps none); a sample out of ``shapes``' order is refused."""
    from litege_core.evaluation.fusion import collect_ood_samples, probe_calibration
    from litege_core.learned import Predictor, load_bundle
    from litege_core.shape import Shape

    shapes = _blob_shapes(blob)
    bundle = load_bundle(toy_bundle_dir_with_ood)
    predictor = Predictor(bundle, fusion="none")
    fitted = dataclasses.replace(
        probe_calibration(bundle.content_hash, 8, 3.0), bias=(1.2,), gate=(0.0, 0.0, 0.0, 0.0)
    )
    samples = collect_ood_samples(predictor, shapes, fitted, ("mesh", "meshnoise_0.004"))
    read = with_cloud_rows(predictor, shapes, samples, fitted)
    assert read[0].as_cloud is None and read[1].as_cloud is not None
    noisy = make_input(shapes[0], "meshnoise_0.004", 0)
    cloud_predictor = Predictor(bundle, fusion=fitted)
    state = cloud_predictor.register(Shape.from_arrays(noisy.shape.vertices))
    np.testing.assert_allclose(
        read[1].as_cloud, cloud_predictor.distances(state, noisy.source_index), rtol=1e-6
    )
    with pytest.raises(ValueError, match="is not"):
        with_cloud_rows(predictor, shapes, [dataclasses.replace(samples[1], shape="other")], fitted)


def test_the_cloud_limit_sends_meshes_the_graph_fails_to_the_cloud_path() -> None:
    """Two kinds of mesh at three noise levels: at the two lower the ring graph (with noise
    knots) beats the cloud of the vertices, at the highest its bias differs between the kinds,
    so knots fitted on the other kind mislead it; the limit lands between the two upper
    levels, and the fused error follows the better path per level."""
    rng = np.random.default_rng(3)
    samples = []
    for setting, noise, biases, cloud_error in (
        ("mesh", 0.02, (1.01, 1.01), 0.05),
        ("meshnoise_0.002", 0.1, (1.02, 1.02), 0.05),
        ("meshnoise_0.004", 0.2, (1.04, 1.04), 0.05),
        ("meshnoise_0.016", 0.6, (1.1, 1.5), 0.02),
    ):
        for i in range(8):
            truth = rng.uniform(10.0, 200.0, size=(4, 50))
            graph = truth * biases[i % 2] * rng.normal(1.0, 0.002, truth.shape)
            as_cloud = truth * (1.0 + cloud_error) if setting != "mesh" else None
            samples.append(
                FusionSample(
                    f"m{i}",
                    f"kind {i % 2}",
                    setting,
                    True,
                    800,
                    0.0,
                    noise,
                    truth,
                    graph,
                    truth,
                    as_cloud=as_cloud,
                )
            )
    clouds = [s for s in _samples() if not s.mesh]
    calibration = fit_fusion(samples + clouds, "h" * 64, k=8, prune_ratio=1.5)
    limit, errors = choose_mesh_cloud_noise(samples, calibration)
    assert list(errors) == [None, pytest.approx(0.4), pytest.approx(0.15)]  # None first
    assert limit == pytest.approx(0.4)
    assert errors[limit] < min(e for v, e in errors.items() if v != limit)
    chosen = dataclasses.replace(calibration, mesh_cloud_noise=limit)
    noisiest = [s for s in samples if s.setting == "meshnoise_0.016"]
    assert np.mean([sample_error(s, chosen, "fused") for s in noisiest]) == pytest.approx(2.0)
    lighter = [s for s in samples if s.setting == "meshnoise_0.004"]
    assert np.mean([sample_error(s, chosen, "fused") for s in lighter]) < 1.0


def test_cut_samples_read_the_fitted_graph_cut_by_the_scorer(
    blob, toy_bundle_dir_with_ood, shipped_toy_scorer
) -> None:
    from litege_core.evaluation.fusion import collect_cut_samples, probe_calibration
    from litege_core.learned import Predictor, load_bundle

    shapes = _blob_shapes(blob)
    bundle = load_bundle(toy_bundle_dir_with_ood)
    predictor = Predictor(bundle)
    fitted = dataclasses.replace(
        probe_calibration(bundle.content_hash, 8, 1e9), bias=(1.2,), gate=(0.0, 0.0, 0.0, 0.0)
    )
    by_cut = collect_cut_samples(predictor, shapes, fitted, (0.5, 1.0), shipped_toy_scorer,
                                 ("cloud_300",))  # fmt: skip
    (cut,), (uncut,) = by_cut[0.5], by_cut[1.0]
    np.testing.assert_array_equal(cut.network, uncut.network)
    # the raw graph (no bias, no blend): the cut only removes edges, so paths only lengthen
    joined = (uncut.graph != uncut.network) & (cut.graph != cut.network)
    assert joined.mean() > 0.3
    assert np.all(cut.graph[joined] >= uncut.graph[joined] - 1e-9)
    assert np.any(cut.graph[joined] > uncut.graph[joined] + 1e-6)
    assert cut.unvetoed is not None and not np.array_equal(cut.unvetoed, uncut.unvetoed)


def test_the_roughness_limit_keeps_the_cut_where_it_helps() -> None:
    """Smooth clouds gain from the cut (their graph's scatter 10 % → 1 %), rough ones lose
    (→ 30 %): the chosen limit separates them, and the samples follow it."""
    from litege_core.evaluation.fusion import choose_cut_roughness

    rng = np.random.default_rng(0)
    uncut, cut = [], []
    for i in range(8):
        rough = i % 2 == 1
        truth = rng.uniform(10.0, 200.0, size=(2, 40))
        network = truth * rng.normal(1.0, 0.2, truth.shape)
        before = truth * 1.15 * rng.normal(1.0, 0.1, truth.shape)
        after = truth * 1.15 * rng.normal(1.0, 0.3 if rough else 0.01, truth.shape)
        roughness = 0.4 if rough else 0.1
        for rows, out in ((before, uncut), (after, cut)):
            out.append(
                FusionSample(f"s{i}", "toy", "cloud_2000", False, 2000, 0.0, roughness,
                             network, rows, truth)
            )  # fmt: skip

    def fit(samples, limit):
        return fit_fusion(samples, "h" * 64, shortcut_cut={"cloud_2000": 0.5},
                          shortcut_scorer="s" * 64, shortcut_max_roughness=limit)  # fmt: skip

    limit, samples, calibration, errors = choose_cut_roughness(uncut, cut, [None, 0.2, 0.05], fit)
    assert limit == 0.2 and set(errors) == {None, 0.2, 0.05}
    assert errors[0.2] < min(errors[None], errors[0.05])
    assert [s.graph is c.graph for s, c in zip(samples, cut, strict=True)] == [
        i % 2 == 0 for i in range(8)
    ]
    assert calibration.shortcut_cut == (0.5,) and calibration.shortcut_max_roughness == 0.2
    assert calibration.shortcut_limit(2000, 0.1) == 0.5
    assert calibration.shortcut_limit(2000, 0.4) == 1.0
