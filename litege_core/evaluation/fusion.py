"""Fit the graph-fusion calibration of a geodesic bundle (:mod:`litege_core.learned.fusion`).

The calibration shapes are ones we generate (held-out procedural shapes, rigged or MakeHuman
bodies): never the real dev set. For each (shape, setting) the network's rows and the pruned
graph's rows are computed once (:func:`collect_samples`); the graph's bias knots are the
per-setting medians (clean clouds) of the shapes' median graph / truth ratios (the mesh bias:
the same median over the clean meshes of both resolutions, whose graph follows the mesh's
connectivity, and which the graph answers alone; its noise knots: :func:`mesh_noise_knots`),
and the four cloud gate constants minimise the mean per-shape error
of the fused rows (Nelder–Mead, from ``w = 1/2``). The normal limit of each clean-cloud knot
is the candidate whose bias-corrected graph has the lowest mean per-shape error at that
density (:func:`choose_normal_limits`); noisy clouds take the limit of their point count. The
veto's OOD limit is the largest candidate of :data:`VETO_MAX_Z_CANDIDATES` (or none), at or
above every z-score of the shapes of the model's kind, whose fusion has a mean error within
:data:`VETO_LIMIT_TOLERANCE` of the lowest (:func:`choose_veto_limit`): it matters only where
the calibration shapes include ones the network does not know (``scripts/build_folder_cal.py
--primitives``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.evaluation.geodesic import EvalShape, make_input
from litege_core.learned.cloud_surface import surface_roughness
from litege_core.learned.fusion import MESH_RINGS, fuse
from litege_core.learned.fusion_calibration import FusionCalibration
from litege_core.learned.mesh_noise import mesh_noise
from litege_core.metrics import geodesic_error

CALIBRATION_SETTINGS = (
    "mesh",
    "decimated_1000",
    "cloud_5000",
    "cloud_2000",
    "cloud_1000",
    "cloud_500",
    "cloud_300",
    "noise_0.005",
    "noise_0.01",
    "noise_0.02",
    "meshnoise_0.002",
    "meshnoise_0.004",
    "meshnoise_0.008",
    "meshnoise_0.016",
)
"""Inputs the calibration covers: the mesh and the mesh simplified to 1000 vertices, clean
clouds from dense to sparse, 2000-point clouds with three noise levels and the mesh with four
levels of vertex noise (unit-area units; ~0.1–1 of the calibration meshes' edge length)."""

DEFAULT_K = 16
DEFAULT_PRUNE_RATIO = 1.6
NORMAL_COS_CANDIDATES = (1.0, 0.9, 0.8, 0.7, 0.6)
"""Normal limits ``scripts/calibrate_fusion.py`` tries per density (1: no normal veto). A lower
limit cuts more chords that cross a thin part or the gap between two parts; a too low one cuts
the surface's own edges where it curves within a neighbourhood (sparse clouds, noise)."""
PRUNE_RATIO_CANDIDATES = (1.1, 1.2, 1.3, 1.6)
"""Veto thresholds ``scripts/calibrate_fusion.py`` tries; the one whose fit has the lowest mean
fused error on the calibration shapes is kept. A lower threshold cuts more shortcuts between
parts that touch (the network under-estimates them too), a too low one cuts true surface edges
of sparse clouds where the veto head over-estimates."""
MESH_ARCS_CANDIDATES = (False, True)
"""Mesh graphs ``scripts/calibrate_fusion.py`` tries: plain chords, or chords lengthened to their
arcs (:func:`choose_mesh_arcs`)."""
DEFAULT_MESH_SMOOTH_NOISE = 0.08
"""The vertex noise above which ``scripts/calibrate_fusion.py`` has a mesh smoothed down to it
before its ring graph (:func:`~litege_core.learned.mesh_noise.denoised_mesh`): just above the
at most ~0.06 that clean meshes read (0.001–0.06 on every dev, calibration and train-data mesh
we have, the denser the lower), so no clean mesh is touched."""
MUTUAL_K_CANDIDATES = (0, 24)
"""Cloud graphs ``scripts/calibrate_fusion.py`` tries: 0, the symmetric k-NN graph, or the
mutual k-NN graph of that many neighbours (:func:`~litege_core.engines.graph.mutual_knn_graph`);
the one whose fit has the lowest mean fused error on the calibration shapes is kept, as for the
veto threshold."""
VETO_MAX_Z_CANDIDATES = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0)
"""OOD z-scores above which :func:`choose_veto_limit` tries turning the network veto off (besides
keeping it on every cloud); real animals and humans score about −1.5 to 3 under their model,
shapes of no training family 8 to 13 (BENCHMARKS "veto-ood")."""
VETO_LIMIT_TOLERANCE = 0.01
"""A lower OOD limit of the veto must lower the calibration's mean fused error by more than this
fraction: :func:`choose_veto_limit` keeps the largest limit (none first) within it of the best,
so the veto stays where the calibration shapes cannot tell (they seldom score between 2 and 6)."""

GATE_OOD_PENALTY = 1000.0
"""Weight of the in-kind excess over its bound in :func:`fit_gate_with_ood`'s objective (a
large one: the bound is a constraint)."""


@dataclass(frozen=True)
class FusionSample:
    """One (shape, setting): ``(S, T)`` network, raw graph and exact rows (one unit), with the
    gate's inputs (mesh or cloud, OOD z-score, point count, surface roughness: a cloud's
    :func:`~litege_core.learned.cloud_surface.surface_roughness`, a mesh's
    :func:`~litege_core.learned.mesh_noise.mesh_noise`)."""

    shape: str
    group: str
    setting: str
    mesh: bool
    n_points: int
    z_score: float
    roughness: float
    network: NDArray
    graph: NDArray
    truth: NDArray
    unvetoed: NDArray | None = None
    """The graph's rows without the network veto (clouds, where collected), else ``None``."""
    as_cloud: NDArray | None = None
    """A noisy mesh's rows answered as the cloud of its vertices by a fitted fusion
    (:func:`with_cloud_rows`), else ``None``."""


def probe_calibration(
    bundle_hash: str,
    k: int,
    prune_ratio: float,
    veto_head: str = "full",
    normal_cos: float = 1.0,
    mutual_k: int = 0,
    mesh_arcs: bool = False,
    mesh_smooth_noise: float | None = None,
) -> FusionCalibration:
    """A calibration whose fused output is the raw pruned graph (weight 0, bias 1): what
    :func:`collect_samples` queries to read the graph through the predictor itself."""
    return FusionCalibration(
        k,
        prune_ratio,
        (3.0,),
        (1.0,),
        (-60.0, 0.0, 0.0, 0.0),
        mesh_bias=1.0,
        bundle_hash=bundle_hash,
        veto_head=veto_head,
        normal_cos=(normal_cos,) if normal_cos < 1.0 else (),
        mutual_k=mutual_k,
        mesh_arcs=mesh_arcs,
        mesh_smooth_noise=mesh_smooth_noise,
    )


GraphVariant = tuple[float, float, int]
"""``(prune_ratio, normal_cos, mutual_k)`` of a cloud graph."""
NEVER_VETO_Z = -1e9
"""A ``veto_max_z`` below every OOD z-score: the probe of a graph without the network veto."""


def collect_samples(
    predictor,
    shapes: Sequence[EvalShape],
    settings: Sequence[str] = CALIBRATION_SETTINGS,
    *,
    k: int = DEFAULT_K,
    prune_ratios: Sequence[float] = (DEFAULT_PRUNE_RATIO,),
    normal_limits: Sequence[float] = (1.0,),
    mutual_ks: Sequence[int] = (0,),
    veto_head: str = "full",
    seed: int = 0,
    mesh_arcs: bool = False,
    mesh_smooth_noise: float | None = None,
) -> dict[GraphVariant, list[FusionSample]]:
    """Network and graph rows of every (shape, setting), inputs as ``evaluate_methods`` makes
    them (``make_input(shape, setting, seed + i)``), for each veto threshold, normal limit and
    neighbour rule, with the same graph's rows without the veto (``FusionSample.unvetoed``).

    Args:
        predictor: a :class:`~litege_core.learned.predictor.Predictor` without fusion.
        shapes: calibration shapes (exact rows at unit area).
        prune_ratios: veto thresholds of the cloud graphs (the network rows are shared).
        normal_limits: normal limits of the cloud graphs (1: none).
        mutual_ks: the cloud graphs' neighbour rules (0: symmetric k-NN; else mutual k-NN of
            that many neighbours).
        veto_head: the head that prunes the graph (see
            :class:`~litege_core.learned.fusion_calibration.FusionCalibration`).
        mesh_arcs: a mesh's graph lengthens its chords to their arcs (:func:`choose_mesh_arcs`).
        mesh_smooth_noise: meshes noisier than this are smoothed down to it before their graph
            (see :class:`~litege_core.learned.fusion_calibration.FusionCalibration`); their samples'
            roughness stays the noise of the mesh as given, what the bias reads.

    Returns:
        ``{(prune_ratio, normal_cos, mutual_k): samples}``, the samples in the same order
        for every variant.
    """
    hash_ = predictor.bundle.content_hash
    meshes = (mesh_arcs, mesh_smooth_noise)
    probes = {
        (ratio, limit, mutual): (
            probe_calibration(hash_, k, ratio, veto_head, limit, mutual, *meshes),
            # the same graph with the veto off (an OOD limit below every z)
            replace(
                probe_calibration(hash_, k, 1.0, veto_head, limit, mutual, *meshes),
                veto_max_z=NEVER_VETO_Z,
            ),
        )
        for ratio in prune_ratios
        for limit in normal_limits
        for mutual in mutual_ks
    }
    return _collect(predictor, shapes, settings, probes, seed)


def collect_ood_samples(
    predictor,
    shapes: Sequence[EvalShape],
    calibration: FusionCalibration,
    settings: Sequence[str] = CALIBRATION_SETTINGS,
    seed: int = 0,
) -> list[FusionSample]:
    """:func:`collect_samples` of shapes the network does not know, with the graph of a fitted
    ``calibration`` (its own normal limits, neighbour rule and veto threshold, the veto on
    every cloud), and without its veto: what :func:`choose_veto_limit` weighs."""
    raw = replace(calibration, bias=(1.0,) * len(calibration.bias), gate=(-60.0, 0.0, 0.0, 0.0))
    probes = {
        "fitted": (
            replace(raw, veto_max_z=None),
            replace(raw, veto_max_z=NEVER_VETO_Z),
        )
    }
    return _collect(predictor, shapes, settings, probes, seed)["fitted"]


SHORTCUT_CUT_CANDIDATES = (1.0,)
"""Cuts of the learned shortcut scorer ``scripts/calibrate_fusion.py`` tries by default (1:
none; ``--shortcut-cut 1,0.5,0.3,0.2`` tries the scorer)."""


def collect_cut_samples(
    predictor,
    shapes: Sequence[EvalShape],
    calibration: FusionCalibration,
    cuts: Sequence[float],
    scorer_sha256: str,
    settings: Sequence[str],
    seed: int = 0,
) -> dict[float, list[FusionSample]]:
    """:func:`collect_samples` of the cloud ``settings`` with ``calibration``'s graph (its
    neighbour rule, normal limits and veto threshold) cut by the learned shortcut scorer above
    each of ``cuts`` at every size and roughness, with and without the veto: ``{cut:
    samples}``, the samples in the order of :func:`collect_samples`."""
    raw = replace(
        calibration,
        bias=(1.0,) * len(calibration.bias),
        gate=(-60.0, 0.0, 0.0, 0.0),
        shortcut_scorer=scorer_sha256,
        shortcut_max_roughness=None,
    )
    probes = {}
    for cut in cuts:
        cutting = replace(raw, shortcut_cut=(float(cut),) * len(calibration.bias))
        probes[cut] = (cutting, replace(cutting, veto_max_z=NEVER_VETO_Z))
    return _collect(predictor, shapes, settings, probes, seed)


def choose_shortcut_cuts(
    by_cut: dict[float, Sequence[FusionSample]],
) -> tuple[dict[str, float], list[FusionSample]]:
    """Per clean-cloud setting, the cut whose bias-corrected graph errs least (the rule of
    :func:`choose_normal_limits`, 1 being no cut), and the samples with their chosen graphs."""
    return choose_normal_limits(by_cut)


def choose_cut_roughness(
    uncut: Sequence[FusionSample],
    cut: Sequence[FusionSample],
    candidates: Sequence[float | None],
    fit: Callable[[list[FusionSample], float | None], FusionCalibration],
) -> tuple[float | None, list[FusionSample], FusionCalibration, dict[float | None, float]]:
    """The roughness above which a cloud is left uncut: of ``candidates`` (``None``: cut
    every cloud), the one whose fusion, fitted by ``fit(samples, roughness)`` on the samples
    with that rule, has the lowest mean fused error (the lower roughness on a tie); returns it,
    its samples, its fit and each candidate's error.

    ``uncut``, ``cut``: the same samples without and with the chosen cuts
    (:func:`choose_shortcut_cuts`)."""
    results: dict[float | None, tuple[float, list[FusionSample], FusionCalibration]] = {}
    for limit in candidates:
        merged = [
            c if not c.mesh and (limit is None or c.roughness <= limit) else u
            for u, c in zip(uncut, cut, strict=True)
        ]
        calibration = fit(merged, limit)
        results[limit] = (mean_fused_error(merged, calibration), merged, calibration)
    best = min(results, key=lambda r: (results[r][0], math.inf if r is None else r))
    errors = {limit: error for limit, (error, _, _) in results.items()}
    return best, results[best][1], results[best][2], errors


def _collect(
    predictor,
    shapes: Sequence[EvalShape],
    settings: Sequence[str],
    probes: dict[Any, tuple[FusionCalibration, FusionCalibration]],
    seed: int,
) -> dict[Any, list[FusionSample]]:
    """The samples of :func:`collect_samples` for each key of ``probes``: ``(vetoed,
    unvetoed)`` calibrations whose fused output is their raw graph (weight 0, bias 1)."""
    from litege_core.learned import Predictor

    def reader(calibration: FusionCalibration) -> Predictor:
        return Predictor(
            predictor.bundle,
            predictor.device,
            descriptor_lattice=predictor.descriptor_lattice,
            head=predictor.head,
            fusion=calibration,
        )

    readers = {
        key: (reader(vetoed), reader(unvetoed)) for key, (vetoed, unvetoed) in probes.items()
    }
    unvetoed_rows: dict[tuple, NDArray] = {}  # readers that differ only in the veto share them
    samples: dict[Any, list[FusionSample]] = {key: [] for key in readers}
    for setting in settings:
        for i, shape in enumerate(shapes):
            item = make_input(shape, setting, seed + i)
            state = predictor.register(item.shape, seed=seed)
            network = predictor.distances(state, item.source_index).astype(np.float64)
            mesh = state.faces is not None
            roughness = (
                mesh_noise(state.canonical_points, state.faces)
                if mesh
                else surface_roughness(state.canonical_points)
            )
            unvetoed_rows.clear()
            for key, (vetoed_reader, unvetoed_reader) in readers.items():
                graph = vetoed_reader.distances(state, item.source_index).astype(np.float64)
                unvetoed = None
                if not mesh:
                    c = unvetoed_reader.fusion
                    assert c is not None
                    shared = (c.k, c.normal_cos, c.bias_log10_points, c.mutual_k, c.shortcut_cut)
                    if shared not in unvetoed_rows:
                        rows = unvetoed_reader.distances(state, item.source_index)
                        unvetoed_rows[shared] = rows.astype(np.float64)
                    unvetoed = unvetoed_rows[shared]
                samples[key].append(
                    FusionSample(
                        shape.name,
                        shape.group,
                        setting,
                        mesh,
                        state.n_points,
                        float(state.ood_score),
                        roughness,
                        network,
                        graph,
                        np.asarray(item.gt, np.float64),
                        unvetoed,
                    )
                )
    return samples


def _median_ratio(members: Sequence[FusionSample]) -> float:
    """The median over samples of each one's median graph / truth ratio (the graph's bias)."""
    ratios = []
    for s in members:
        keep = (s.truth > 0) & np.isfinite(s.graph)
        ratios.append(float(np.median(s.graph[keep] / s.truth[keep])))
    return float(np.median(ratios))


def choose_mesh_arcs(
    by_arcs: dict[bool, Sequence[FusionSample]],
) -> tuple[bool, dict[bool, float]]:
    """Whether a mesh's graph lengthens its chords to their arcs: the candidate whose mesh
    rows, divided by their median bias (as the fitted calibration applies it), have the lowest
    mean per-shape error (plain chords on a tie), and each candidate's error.

    ``by_arcs``: ``{mesh_arcs: mesh samples}`` (:func:`collect_samples` of the ``"mesh"``
    setting with each value: clean meshes, the inputs a mesh graph is chosen for; vertex
    noise only moves its bias, :func:`mesh_noise_knots`).
    """
    errors = {}
    for arcs, members in by_arcs.items():
        bias = _median_ratio(members)
        rows = [_graph_or_network(s) / bias for s in members]
        errors[arcs] = float(
            np.mean([_error(r, s.truth) for r, s in zip(rows, members, strict=True)])
        )
    return min(errors, key=lambda arcs: (errors[arcs], arcs)), errors


CLEAN_MESH_NOISE_QUANTILE = 0.9
"""The clean meshes' knot sits at this quantile of their vertex noise: a mesh as smooth as most
clean calibration meshes keeps their bias (clean meshes' noise comes from their curvature and
triangulation, not from noise, and does not move their bias)."""


def is_clean_mesh(sample: FusionSample) -> bool:
    """Whether ``sample`` is a clean mesh: a mesh input of any resolution (``mesh``,
    ``decimated_N``), not one with vertex noise (``meshnoise_S``)."""
    return sample.mesh and not sample.setting.startswith("meshnoise")


def mesh_noise_knots(
    meshes: Sequence[FusionSample],
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The noise knots of a mesh graph's bias: the clean meshes' (:func:`is_clean_mesh`) at
    the :data:`CLEAN_MESH_NOISE_QUANTILE` of their vertex noise
    (:func:`~litege_core.learned.mesh_noise.mesh_noise`) with their median bias, then per noisy
    setting (``meshnoise_S``) the median noise of its samples with their median bias, in
    increasing noise (a noisy setting no noisier than the knot before it is left out); empty
    where fewer than two knots remain (a constant bias)."""
    clean = [s for s in meshes if is_clean_mesh(s)]
    by_setting: dict[str, list[FusionSample]] = {}
    for sample in meshes:
        if not is_clean_mesh(sample):
            by_setting.setdefault(sample.setting, []).append(sample)
    noisy = sorted(
        (float(np.median([s.roughness for s in members])), _median_ratio(members))
        for members in by_setting.values()
    )
    knots: list[tuple[float, float]] = []
    if clean:
        noise = float(np.quantile([s.roughness for s in clean], CLEAN_MESH_NOISE_QUANTILE))
        knots.append((noise, _median_ratio(clean)))
    for noise, bias in noisy:
        if not knots or noise > knots[-1][0]:
            knots.append((noise, bias))
    if len(knots) < 2:
        return (), ()
    return tuple(x for x, _ in knots), tuple(b for _, b in knots)


def with_cloud_rows(
    predictor,
    shapes: Sequence[EvalShape],
    samples: Sequence[FusionSample],
    calibration: FusionCalibration,
    seed: int = 0,
) -> list[FusionSample]:
    """``samples`` with each noisy mesh's (``meshnoise_S``) rows answered as the cloud of its
    vertices by ``calibration`` (``FusionSample.as_cloud``), what :func:`choose_mesh_cloud_noise`
    weighs. The noisy meshes are made again as :func:`collect_samples` made them (each
    setting's samples in ``shapes``' order, seed ``seed + i``)."""
    from litege_core.learned import Predictor
    from litege_core.shape import Shape

    fused = Predictor(
        predictor.bundle,
        predictor.device,
        descriptor_lattice=predictor.descriptor_lattice,
        head=predictor.head,
        fusion=replace(calibration, mesh_cloud_noise=None),
    )
    out = list(samples)
    for setting in sorted({s.setting for s in samples if s.mesh and not is_clean_mesh(s)}):
        index = [k for k, s in enumerate(samples) if s.setting == setting]
        if len(index) != len(shapes):
            raise ValueError(f"{setting}: {len(index)} samples for {len(shapes)} shapes")
        for i, (k, shape) in enumerate(zip(index, shapes, strict=True)):
            if samples[k].shape != shape.name:
                raise ValueError(f"{setting}: sample {samples[k].shape} is not {shape.name}")
            item = make_input(shape, setting, seed + i)
            state = fused.register(Shape.from_arrays(item.shape.vertices), seed=seed)
            rows = fused.distances(state, item.source_index).astype(np.float64)
            out[k] = replace(samples[k], as_cloud=rows)
    return out


def choose_mesh_cloud_noise(
    samples: Sequence[FusionSample], calibration: FusionCalibration
) -> tuple[float | None, dict[float | None, float]]:
    """The vertex noise above which a mesh is answered as the cloud of its vertices: of
    ``None`` (never) and the midpoints between the noisy settings' median noises, the one whose
    mean error over the mesh samples is lowest (``None``, then the highest, on a tie), and each
    one's error. A noisy mesh answered by its ring graph is scored with the bias of noise
    knots fitted on the other groups' meshes (:func:`mesh_noise_knots`; its own group's where
    there is no other): how far the bias carries to another kind of mesh at that noise, not how
    well it fits its own (the graph's over-estimate at a given noise differs from one kind of
    mesh to another, the more so the noisier, and a bias off by a few percent costs more than
    the cloud path). The noisy meshes need their cloud rows (:func:`with_cloud_rows`)."""
    meshes = [s for s in samples if s.mesh]
    noisy: dict[str, list[FusionSample]] = {}
    for s in meshes:
        if s.as_cloud is not None:
            noisy.setdefault(s.setting, []).append(s)
    by_graph = replace(calibration, mesh_cloud_noise=None)
    held_out = {}
    for group in {s.group for s in meshes}:
        others = [s for s in meshes if s.group != group]
        if others:
            knots, bias = mesh_noise_knots(others)
            held_out[group] = replace(by_graph, mesh_noise_knots=knots, mesh_noise_bias=bias)
    graph_errors = [sample_error(s, held_out.get(s.group, by_graph), "fused") for s in meshes]
    cloud_errors = [math.inf if s.as_cloud is None else _error(s.as_cloud, s.truth) for s in meshes]
    medians = sorted(float(np.median([s.roughness for s in m])) for m in noisy.values())
    candidates: list[float | None] = [None]
    candidates += sorted(((a + b) / 2 for a, b in itertools.pairwise(medians)), reverse=True)
    errors = {}
    for limit in candidates:
        as_cloud = [limit is not None and s.roughness > limit for s in meshes]
        chosen = [
            c if cloud else g
            for g, c, cloud in zip(graph_errors, cloud_errors, as_cloud, strict=True)
        ]
        errors[limit] = float(np.mean(chosen))
    lowest = min(errors.values())
    return next(limit for limit, error in errors.items() if error <= lowest), errors


def choose_normal_limits(
    by_limit: dict[float, Sequence[FusionSample]],
) -> tuple[dict[str, float], list[FusionSample]]:
    """Per clean-cloud setting, the normal limit whose graph (divided by its median bias at
    that setting) has the lowest mean per-shape error, and the samples of every setting with
    their chosen graphs (meshes ignore the limit; a noisy or cut cloud of N points takes the
    candidate nearest the limit interpolated at N, as the fitted calibration applies it).

    ``by_limit``: ``{normal_cos: samples}``, the same samples in the same order for each.
    """
    limits = sorted(by_limit)
    reference = list(by_limit[limits[-1]])
    chosen: dict[str, float] = {}
    for setting in sorted({s.setting for s in reference if s.setting.startswith("cloud_")}):
        index = [i for i, s in enumerate(reference) if s.setting == setting]

        def error(limit: float, index: list[int] = index) -> float:
            members = [by_limit[limit][i] for i in index]
            bias = _median_ratio(members)
            return float(np.mean([_error(_graph_or_network(s) / bias, s.truth) for s in members]))

        chosen[setting] = min(limits, key=lambda limit: (error(limit), -limit))
    if not chosen:
        return chosen, reference
    knots = sorted(
        (float(np.log10(np.mean([s.n_points for s in reference if s.setting == setting]))), c)
        for setting, c in chosen.items()
    )
    log_points, knot_limits = [x for x, _ in knots], [c for _, c in knots]
    merged = []
    for i, sample in enumerate(reference):
        limit = limits[-1]
        if not sample.mesh:
            target = float(np.interp(np.log10(sample.n_points), log_points, knot_limits))
            limit = min(limits, key=lambda c: (abs(c - target), -c))
        merged.append(by_limit[limit][i])
    return chosen, merged


def _graph_or_network(sample: FusionSample) -> NDArray:
    """The sample's graph rows, the network's value where the graph joins no path."""
    return np.where(np.isfinite(sample.graph), sample.graph, sample.network)


def _error(rows: NDArray, truth: NDArray) -> float:
    keep = truth > 0
    return geodesic_error(rows[keep], truth[keep]).mean


def sample_error(sample: FusionSample, calibration: FusionCalibration | None, what: str) -> float:
    """The sample's mean error (GT mean 100) of ``what``: ``"network"``, ``"graph"`` (raw,
    unreachable pairs given the network's value) or ``"fused"``."""
    graph = _graph_or_network(sample)
    if what == "network":
        return _error(sample.network, sample.truth)
    if what == "graph":
        return _error(graph, sample.truth)
    assert calibration is not None
    if sample.as_cloud is not None and calibration.answers_as_cloud(sample.roughness):
        return _error(sample.as_cloud, sample.truth)
    rows = fuse(
        sample.network,
        sample.graph,
        calibration,
        sample.z_score,
        sample.n_points,
        sample.roughness,
        sample.mesh,
    )
    return _error(rows, sample.truth)


def fit_fusion(
    samples: Sequence[FusionSample],
    bundle_hash: str,
    *,
    k: int = DEFAULT_K,
    prune_ratio: float = DEFAULT_PRUNE_RATIO,
    veto_head: str = "full",
    fitted_on: dict[str, Any] | None = None,
    normal_cos: dict[str, float] | None = None,
    mutual_k: int = 0,
    mesh_arcs: bool = False,
    mesh_smooth_noise: float | None = None,
    shortcut_cut: dict[str, float] | None = None,
    shortcut_scorer: str = "",
    shortcut_max_roughness: float | None = None,
) -> FusionCalibration:
    """Bias knots and the cloud gate fitted on ``samples`` (see the module docstring); without
    mesh samples the mesh bias is 1.
    ``normal_cos``: the normal limit of each clean-cloud setting the samples' graphs were
    built with (:func:`choose_normal_limits`), or ``None``: no normal limit; ``mutual_k``:
    the neighbour rule they were built with; ``mesh_arcs``, ``mesh_smooth_noise``: the mesh
    graph they were built with (:func:`choose_mesh_arcs`, :func:`collect_samples`);
    ``shortcut_cut``, ``shortcut_scorer``, ``shortcut_max_roughness``: the learned cut they
    were built with (:func:`choose_shortcut_cuts`), or ``None``: none."""
    clouds = [s for s in samples if not s.mesh]
    meshes = [s for s in samples if s.mesh]
    clean = [s for s in meshes if is_clean_mesh(s)] or meshes
    noise_knots, noise_bias = mesh_noise_knots(meshes)
    knots: dict[str, tuple[float, float, float, float]] = {}
    for setting in sorted({s.setting for s in clouds if s.setting.startswith("cloud_")}):
        members = [s for s in clouds if s.setting == setting]
        knots[setting] = (
            float(np.log10(np.mean([s.n_points for s in members]))),
            _median_ratio(members),
            1.0 if normal_cos is None else normal_cos[setting],
            1.0 if shortcut_cut is None else shortcut_cut[setting],
        )
    ordered = sorted(knots.values())
    base = FusionCalibration(
        k,
        prune_ratio,
        tuple(x for x, _, _, _ in ordered),
        tuple(b for _, b, _, _ in ordered),
        (0.0, 0.0, 0.0, 0.0),
        mesh_bias=_median_ratio(clean) if clean else 1.0,
        bundle_hash=bundle_hash,
        fitted_on=dict(fitted_on or {}),
        veto_head=veto_head,
        normal_cos=() if normal_cos is None else tuple(c for _, _, c, _ in ordered),
        mutual_k=mutual_k,
        mesh_arcs=mesh_arcs,
        mesh_noise_knots=noise_knots,
        mesh_noise_bias=noise_bias,
        mesh_smooth_noise=mesh_smooth_noise,
        shortcut_cut=() if shortcut_cut is None else tuple(c for _, _, _, c in ordered),
        shortcut_scorer=shortcut_scorer if shortcut_cut is not None else "",
        shortcut_max_roughness=shortcut_max_roughness if shortcut_cut is not None else None,
    )

    if clouds:
        base = replace(base, gate=fit_gate(clouds, base))
    return base


def fit_gate(
    samples: Sequence[FusionSample], calibration: FusionCalibration
) -> tuple[float, float, float, float]:
    """The cloud gate ``(a, c_z, c_n, c_r)`` minimising the mean fused error of the cloud
    samples under ``calibration``'s other constants (Nelder–Mead from ``w = 1/2``)."""
    clouds = [s for s in samples if not s.mesh]
    return _minimize_gate(
        lambda gate: mean_fused_error(clouds, gate), calibration, (0.0, 0.0, 0.0, 0.0)
    )


def fit_gate_with_ood(
    samples: Sequence[FusionSample],
    ood_samples: Sequence[FusionSample],
    calibration: FusionCalibration,
    tolerance: float,
) -> tuple[float, float, float, float]:
    """The cloud gate that lowers the mean fused error of ``ood_samples`` (clouds of no
    training family) as far as it can while the mean over the clouds of ``samples`` (the
    model's own kind) stays within ``tolerance`` (a fraction) of what ``calibration``'s gate
    gives them; ``calibration``'s gate where no such gate does better on the OOD clouds. Both
    sets are read as ``calibration``'s veto limit reads them (:func:`with_veto_limit`).

    Not used by the shipped calibrations: on FAUST even 0.25 % cost 0.02–0.04 of fused error
    (1 %: 0.06–0.10), for 3.40 → 3.20 on held-out solids (BENCHMARKS "ood-gate")."""
    clouds = [s for s in samples if not s.mesh]
    unusual = [s for s in ood_samples if not s.mesh]
    if not clouds or not unusual:
        return calibration.gate
    bound = mean_fused_error(clouds, calibration) * (1.0 + tolerance)

    def objective(gate: FusionCalibration) -> float:
        excess = max(0.0, mean_fused_error(clouds, gate) - bound)
        return mean_fused_error(unusual, gate) + GATE_OOD_PENALTY * excess

    # from the in-kind gate and from w = 1/2 (a saturated gate is flat: the search stalls)
    starts = (calibration.gate, (0.0, 0.0, 0.0, 0.0))
    fits = [_minimize_gate(objective, calibration, start) for start in starts]
    fitted = min(fits, key=lambda gate: objective(replace(calibration, gate=gate)))
    refit = replace(calibration, gate=fitted)
    keeps_kind = mean_fused_error(clouds, refit) <= bound
    gains = mean_fused_error(unusual, refit) < mean_fused_error(unusual, calibration)
    return fitted if keeps_kind and gains else calibration.gate


def _minimize_gate(
    objective: Callable[[FusionCalibration], float],
    calibration: FusionCalibration,
    start: tuple[float, float, float, float],
) -> tuple[float, float, float, float]:
    """The gate minimising ``objective`` of ``calibration`` with that gate, by Nelder–Mead
    from ``start`` with unit steps (scipy's default simplex is 0.00025 wide around zero)."""
    from scipy.optimize import minimize

    def with_gate(gate: NDArray) -> FusionCalibration:
        a, c_z, c_n, c_r = (float(v) for v in gate)
        return replace(calibration, gate=(a, c_z, c_n, c_r))

    origin = np.asarray(start, dtype=np.float64)
    fitted = minimize(
        lambda gate: objective(with_gate(gate)),
        origin,
        method="Nelder-Mead",
        options={
            "xatol": 1e-3,
            "fatol": 1e-4,
            "maxiter": 2000,
            "initial_simplex": np.vstack([origin, origin + np.eye(origin.size)]),
        },
    ).x
    return with_gate(fitted).gate


def mean_fused_error(samples: Sequence[FusionSample], calibration: FusionCalibration) -> float:
    """The mean over ``samples`` of their fused error (what :func:`fit_fusion` minimises)."""
    return float(np.mean([sample_error(s, calibration, "fused") for s in samples]))


def with_veto_limit(
    samples: Sequence[FusionSample], calibration: FusionCalibration
) -> list[FusionSample]:
    """``samples`` with each cloud's graph rows as ``calibration`` reads them: the unvetoed
    rows where its ``veto_max_z`` keeps the veto off at the sample's z-score
    (:meth:`~litege_core.learned.fusion_calibration.FusionCalibration.vetoes`)."""
    return [
        replace(s, graph=s.unvetoed)
        if s.unvetoed is not None and not calibration.vetoes(s.z_score)
        else s
        for s in samples
    ]


def choose_veto_limit(
    samples: Sequence[FusionSample],
    calibration: FusionCalibration,
    candidates: Sequence[float] = VETO_MAX_Z_CANDIDATES,
    floor: float = -math.inf,
) -> tuple[FusionCalibration, list[FusionSample], dict[float | None, float]]:
    """The OOD limit of the network veto (``veto_max_z``: one of ``candidates`` at or above
    ``floor``, or none) read with ``calibration``'s gate: the largest whose mean fused error
    over ``samples`` is within :data:`VETO_LIMIT_TOLERANCE` of the lowest (none counts as the
    largest). ``floor``: the highest z-score of the shapes the veto must keep serving (the
    calibration shapes of the model's own kind: a limit below it would take the veto from
    shapes like those it was fitted for).

    Returns the calibration with that limit, the samples as it reads them
    (:func:`with_veto_limit`) and the mean fused error of each option tried (``None``: no
    limit). Without unvetoed rows in ``samples``: ``calibration`` as it is, nothing tried."""
    if not candidates or not any(s.unvetoed is not None for s in samples):
        return calibration, list(samples), {}
    fits = {}
    for limit in [None, *sorted((c for c in candidates if c >= floor), reverse=True)]:
        limited = replace(calibration, veto_max_z=limit)
        read = with_veto_limit(samples, limited)
        clouds = [s for s in read if not s.mesh]  # the veto does not touch a mesh
        fits[limit] = (mean_fused_error(clouds, limited), limited, read)
    lowest = min(error for error, _, _ in fits.values())
    best = next(z for z, (e, _, _) in fits.items() if e <= lowest * (1.0 + VETO_LIMIT_TOLERANCE))
    _, chosen, read = fits[best]
    return chosen, read, {limit: error for limit, (error, _, _) in fits.items()}


def fusion_summary(
    samples: Sequence[FusionSample], calibration: FusionCalibration
) -> list[dict[str, Any]]:
    """Per (group, setting): the shape count, the mean per-shape error of the network, the raw
    pruned graph and the fused rows, the mean roughness and the mean network weight."""
    summary = []
    settings = CALIBRATION_SETTINGS + tuple(
        sorted({s.setting for s in samples} - set(CALIBRATION_SETTINGS))
    )
    for group in sorted({s.group for s in samples}):
        for setting in settings:
            members = [s for s in samples if s.group == group and s.setting == setting]
            if not members:
                continue
            row: dict[str, Any] = {"group": group, "setting": setting, "shapes": len(members)}
            for what in ("network", "graph", "fused"):
                errors = [sample_error(s, calibration, what) for s in members]
                row[what] = round(float(np.mean(errors)), 4)
            row["roughness"] = round(float(np.mean([s.roughness for s in members])), 4)
            weights = [
                calibration.network_weight(s.z_score, s.n_points, s.roughness, s.mesh)
                for s in members
            ]
            row["network_weight"] = round(float(np.mean(weights)), 4)
            summary.append(row)
    return summary


def fusion_table(summary: Sequence[dict[str, Any]], k: int) -> str:
    """Markdown of :func:`fusion_summary`."""
    lines = [
        f"| shapes | setting | n | network | graph (mesh: {MESH_RINGS}-ring; cloud: pruned kNN, "
        f"k = {k}) | fused | roughness (mesh: vertex noise) | network weight |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['group']} | {r['setting']} | {r['shapes']} | {r['network']:.2f} | "
        f"{r['graph']:.2f} | {r['fused']:.2f} | {r['roughness']:.3f} | {r['network_weight']:.2f} |"
        for r in summary
    ]
    return "\n".join(lines)


__all__ = [
    "CALIBRATION_SETTINGS",
    "CLEAN_MESH_NOISE_QUANTILE",
    "DEFAULT_MESH_SMOOTH_NOISE",
    "MESH_ARCS_CANDIDATES",
    "MUTUAL_K_CANDIDATES",
    "NORMAL_COS_CANDIDATES",
    "SHORTCUT_CUT_CANDIDATES",
    "VETO_MAX_Z_CANDIDATES",
    "FusionSample",
    "GraphVariant",
    "choose_cut_roughness",
    "choose_mesh_arcs",
    "choose_mesh_cloud_noise",
    "choose_normal_limits",
    "choose_shortcut_cuts",
    "choose_veto_limit",
    "collect_cut_samples",
    "collect_ood_samples",
    "collect_samples",
    "fit_fusion",
    "fit_gate",
    "fusion_summary",
    "fusion_table",
    "is_clean_mesh",
    "mean_fused_error",
    "mesh_noise_knots",
    "probe_calibration",
    "sample_error",
    "with_cloud_rows",
    "with_veto_limit",
]
