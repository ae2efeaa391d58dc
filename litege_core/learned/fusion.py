"""Graph fusion: the network's distances blended with a calibrated graph Dijkstra.

On real shapes the network's error is dominated by shapes far from its training families (the
error follows the out-of-distribution score), while a graph Dijkstra on a dense cloud is nearly
unbiased wherever its graph has no shortcuts, and on a sparse one is poor everywhere. The fused
estimate takes the better of the two per shape, with weights fitted on data we generate
(procedural shapes, posed rigged animals, MakeHuman bodies; never the real dev set)::

    G_graph  = for a mesh input, Dijkstra on chords between vertices at most ``MESH_RINGS``
               mesh edges apart (the mesh's connectivity: no shortcut between parts that
               touch), where the calibration says so (``mesh_arcs``) lengthened to the arcs
               they span (from the vertex normals: a chord across two rings of a coarse mesh
               cuts through a curved part), on a mesh noisier than the calibration's
               ``mesh_smooth_noise`` after smoothing it down to that noise (a raw scan's
               paths would zig-zag with its vertices:
               :func:`~litege_core.learned.mesh_noise.denoised_mesh`); for a point cloud, on
               the symmetric k-NN graph of the points (canonical frame) after cutting every
               edge whose predicted geodesic exceeds ``prune_ratio`` × its chord (the network
               vetoes shortcuts between touching parts; the veto is the bundle's small head
               where the calibration says so: it costs one head evaluation per edge, ~8 N for
               N points) and, where the calibration has normal limits, every edge whose chord
               runs along the surface normal at either end, ``|n · ĉ| > c(N)`` (a chord
               across a thin part or a gap between parts; ``n`` from the points' k-NN
               covariance, ``c(N)`` interpolated in log10 N from calibration knots: looser on
               sparse clouds, whose chords bend with the surface); where the calibration
               says so (``mutual_k``), the graph is the *mutual* k-NN graph of that many
               neighbours instead (fewer chords across thin parts:
               :func:`~litege_core.engines.graph.mutual_knn_graph`); no network veto on a
               cloud whose OOD z-score exceeds ``veto_max_z`` (where the calibration has one:
               the network's edge predictions on a shape it does not know cut true surface
               edges, e.g. a torus at 300 points: 3.4 → 12.2)
    b        = the graph's median over-estimate (zig-zag paths): on a mesh ``mesh_bias``,
               or where the calibration has noise knots b(ν) at the mesh's vertex noise ν
               (:func:`mesh_noise`: a raw scan's noisy vertices lengthen every path, less
               so once smoothed),
               interpolated from them (extrapolated beyond the noisiest); b(N) at N cloud
               points, interpolated in log10 N from calibration knots
    w        = 0 on a mesh (its ring graph alone); for a cloud
               sigmoid(a + c_z · z + c_n · (log10 N − 3) + c_r · r)
               (z: the shape's OOD z-score; r: its surface roughness, see
               :func:`surface_roughness`, high on noisy scans)
    G        = w · G_network + (1 − w) · G_graph / b

so a shape the network knows (low z), a sparse or a noisy cloud leans on the network, and an
unusual shape sampled densely leans on the graph. A mesh is answered by its ring graph alone: a
fitted weight was below 2 % on our generated meshes and dropping it lowered the real dev meshes'
error (BENCHMARKS "mesh-graph-alone"), so a mesh query evaluates no network unless its graph
cannot join a pair. Pairs the graph cannot join (another component) keep the network's value.
A fused predictor's paths follow the same graphs (``route="auto"`` of
:func:`~litege_core.learned.paths.trace_paths`: an edge-flip geodesic on a mesh, the fully vetoed
k-NN graph's shortest path on a cloud).

The calibration is a sidecar of the bundle, like the small head: ``fusion.json`` beside the
bundle files, naming the content hash of the bundle it was fitted for (a mismatch is refused),
written by :func:`save_fusion` (``scripts/calibrate_fusion.py``), read by :func:`load_fusion`
(``Predictor(bundle, fusion="graph")``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from litege_core.arrays import distinct_indices
from litege_core.errors import ArtifactError, InputError
from litege_core.files import read_json_object, write_json_atomic
from litege_core.learned.mesh_noise import denoised_mesh, mesh_noise
from litege_core.learned.veto_graph import (
    LAZY_SOURCES,
    MAX_ROUNDS,
    EdgeGeodesics,
    LazyVetoGraph,
    path_edges,
    reads_trees,
)

if TYPE_CHECKING:  # scipy loads on first use: a plain CLI query never imports it
    import scipy.sparse as sp

FUSION_CONFIG = "fusion.json"
FUSION_KIND = "graph_fusion"
FUSION_FORMAT = 10
"""Format 3 added ``mesh_bias`` and ``mesh_gate`` (meshes use their own connectivity), format 4
``normal_cos`` (a format-3 file reads as one without normal limits), format 5 dropped
``mesh_gate`` (a mesh is answered by its graph alone; older files' gate is ignored), format 6
added ``mutual_k`` (older files read as 0: the symmetric k-NN graph), format 7
``veto_max_z`` (older files read as ``None``: the veto on every cloud), format 8
``mesh_arcs`` (older files read as ``False``: plain chords), format 9 ``mesh_noise_knots``,
``mesh_noise_bias`` (older files read as empty: ``mesh_bias`` at every noise) and
``mesh_cloud_noise`` (older files read as ``None``: every mesh its ring graph), format 10
``mesh_smooth_noise`` (older files read as ``None``: every mesh's ring graph on its own
vertices)."""
READABLE_FORMATS = (3, 4, 5, 6, 7, 8, 9, FUSION_FORMAT)

FUSIONS = ("auto", "none", "graph")
"""Values of the predictors' ``fusion``: ``auto`` (the default: ``graph`` where the bundle ships
a calibration, else ``none``), ``none`` (the network alone) or ``graph``."""
DEFAULT_FUSION = "auto"
VETO_HEADS = ("full", "small")
MESH_RINGS = 2
"""Mesh edges between two vertices the graph of a mesh input joins by a chord
(:func:`~litege_core.engines.graph.mesh_ring_graph`): on the real dev meshes and the calibration
meshes two rings gave the lowest error of 1–3 (the own edges zig-zag, three admit shortcuts)."""
ROUGHNESS_NEIGHBOURS = 16
"""Points per neighbourhood of :func:`surface_roughness` (the point itself included)."""
ROUGHNESS_CHUNK = 65_536
"""Points per block of :func:`surface_roughness` (bounds its ``(C, k, 3)`` temporaries)."""


@dataclass(frozen=True)
class FusionCalibration:
    """Fitted constants of the fusion (see the module docstring).

    Attributes:
        k: neighbours per point of the graph.
        prune_ratio: an edge is cut when its predicted geodesic exceeds this × its chord.
        bias_log10_points: increasing knots of ``log10 N``.
        bias: the graph's median distance / true distance at each knot.
        gate: ``(a, c_z, c_n, c_r)`` of the network's weight ``w`` on a point cloud.
        mesh_bias: the mesh graph's median distance / true distance.
        bundle_hash: content hash of the bundle the calibration belongs to.
        fitted_on: what it was fitted on (free-form JSON: data, counts, errors).
        veto_head: the head whose edge predictions prune the graph: ``"small"`` (the
            bundle's distilled head, ~18× cheaper per pair: what the shipped calibrations use)
            or ``"full"``; whatever head answers the queries.
        normal_cos: the normal limit ``c`` at each bias knot (a cloud edge is cut when
            ``|n · ĉ| > c`` at either end), or empty: no normal limit.
        mutual_k: 0: a cloud's graph joins each point to its ``k`` nearest (symmetric k-NN);
            else the mutual k-NN graph of this many neighbours.
        veto_max_z: the network veto runs on clouds whose OOD z-score is at most this
            (:meth:`vetoes`); ``None``: on every cloud.
        mesh_arcs: a mesh's ring graph lengthens its chords to the arcs they span
            (:func:`~litege_core.engines.graph.mesh_ring_graph`); ``False``: plain chords.
        mesh_noise_knots: increasing knots of a mesh's vertex noise (:func:`mesh_noise`), or
            empty: ``mesh_bias`` whatever the noise.
        mesh_noise_bias: the mesh graph's median distance / true distance at each noise knot.
        mesh_cloud_noise: a mesh whose vertex noise exceeds this is answered as the cloud of
            its vertices (:meth:`answers_as_cloud`: noise beyond the edge length makes every
            ring-graph path zig-zag); ``None``: every mesh by its ring graph.
        mesh_smooth_noise: a mesh whose vertex noise exceeds this is smoothed until it does
            not before its ring graph is built
            (:func:`~litege_core.learned.mesh_noise.denoised_mesh`; its bias still reads the
            noise of the mesh as given: the noise knots were fitted on smoothed graphs);
            ``None``: the ring graph on the mesh's own vertices. Excludes
            ``mesh_cloud_noise``.
    """

    k: int
    prune_ratio: float
    bias_log10_points: tuple[float, ...]
    bias: tuple[float, ...]
    gate: tuple[float, float, float, float]
    mesh_bias: float
    bundle_hash: str
    fitted_on: dict[str, Any] = field(default_factory=dict, compare=False)
    veto_head: str = "full"
    normal_cos: tuple[float, ...] = ()
    mutual_k: int = 0
    veto_max_z: float | None = None
    mesh_arcs: bool = False
    mesh_noise_knots: tuple[float, ...] = ()
    mesh_noise_bias: tuple[float, ...] = ()
    mesh_cloud_noise: float | None = None
    mesh_smooth_noise: float | None = None

    def __post_init__(self) -> None:
        knots, bias = np.asarray(self.bias_log10_points), np.asarray(self.bias)
        if not (isinstance(self.k, int) and self.k >= 1):
            raise ArtifactError(f"fusion k must be a positive integer, got {self.k!r}")
        if not (math.isfinite(self.prune_ratio) and self.prune_ratio >= 1.0):
            raise ArtifactError(f"fusion prune_ratio must be >= 1, got {self.prune_ratio!r}")
        if knots.size < 1 or knots.shape != bias.shape or np.any(np.diff(knots) <= 0):
            raise ArtifactError("fusion bias knots must be increasing, one bias per knot")
        if not (np.all(np.isfinite(bias)) and np.all(bias > 0)):
            raise ArtifactError("fusion bias values must be positive and finite")
        if self.veto_head not in VETO_HEADS:
            raise ArtifactError(f"fusion veto_head must be {VETO_HEADS}, got {self.veto_head!r}")
        if len(self.gate) != 4 or not all(math.isfinite(v) for v in self.gate):
            raise ArtifactError(f"fusion gate must be four finite numbers, got {self.gate!r}")
        if not (math.isfinite(self.mesh_bias) and self.mesh_bias > 0):
            raise ArtifactError(f"fusion mesh_bias must be positive, got {self.mesh_bias!r}")
        limits = np.asarray(self.normal_cos, dtype=np.float64)
        valid = limits.shape == knots.shape and np.all((limits > 0) & (limits <= 1))
        if limits.size and not valid:
            raise ArtifactError("fusion normal_cos must be empty or one value in (0, 1] per knot")
        if not (isinstance(self.mutual_k, int) and self.mutual_k >= 0):
            raise ArtifactError(f"fusion mutual_k must be an integer >= 0, got {self.mutual_k!r}")
        noise, noise_bias = np.asarray(self.mesh_noise_knots), np.asarray(self.mesh_noise_bias)
        if noise.shape != noise_bias.shape or np.any(np.diff(noise) <= 0):
            raise ArtifactError("fusion mesh noise knots must be increasing, one bias per knot")
        if not (np.all(np.isfinite(noise)) and np.all(np.isfinite(noise_bias) & (noise_bias > 0))):
            raise ArtifactError("fusion mesh noise knots and biases must be finite, biases > 0")
        cloud_noise = self.mesh_cloud_noise
        if cloud_noise is not None and not (math.isfinite(cloud_noise) and cloud_noise > 0):
            raise ArtifactError(f"fusion mesh_cloud_noise must be positive, got {cloud_noise!r}")
        smooth_noise = self.mesh_smooth_noise
        if smooth_noise is not None and not (math.isfinite(smooth_noise) and smooth_noise > 0):
            raise ArtifactError(f"fusion mesh_smooth_noise must be positive, got {smooth_noise!r}")
        if smooth_noise is not None and cloud_noise is not None:
            raise ArtifactError("fusion mesh_smooth_noise and mesh_cloud_noise exclude each other")
        if self.veto_max_z is not None and not math.isfinite(self.veto_max_z):
            raise ArtifactError(
                f"fusion veto_max_z must be finite or None, got {self.veto_max_z!r}"
            )

    def vetoes(self, z_score: float) -> bool:
        """Whether the network vetoes the graph edges of a cloud of this OOD z-score: always
        without ``veto_max_z``, else where ``z_score <= veto_max_z`` (never for a ``nan``)."""
        return self.veto_max_z is None or float(z_score) <= self.veto_max_z

    def answers_as_cloud(self, noise: float) -> bool:
        """Whether a mesh of this vertex noise (:func:`mesh_noise`) is answered as the cloud of
        its vertices (above ``mesh_cloud_noise``), not by its ring graph."""
        return self.mesh_cloud_noise is not None and noise > self.mesh_cloud_noise

    def graph_bias(self, n_points: int, mesh: bool = False, noise: float = 0.0) -> float:
        """The graph's over-estimate factor: on a mesh of vertex ``noise``
        (:func:`mesh_noise`) interpolated in the noise knots (the first knot's below them,
        the last segment extended beyond them; ``mesh_bias`` without knots), else at
        ``n_points`` cloud points (clamped to the knots)."""
        if not mesh:
            return float(np.interp(np.log10(n_points), self.bias_log10_points, self.bias))
        knots, bias = self.mesh_noise_knots, self.mesh_noise_bias
        if not knots:
            return self.mesh_bias
        if len(knots) > 1 and noise > knots[-1]:
            slope = (bias[-1] - bias[-2]) / (knots[-1] - knots[-2])
            return float(max(bias[-1] + slope * (noise - knots[-1]), bias[-1]))
        return float(np.interp(noise, knots, bias))

    @property
    def reach(self) -> int:
        """Neighbours per point a cloud's graph searches: ``k``, or ``mutual_k`` for a
        larger mutual graph (:func:`pruned_knn_graph` takes a search of at least this many)."""
        return max(self.k, self.mutual_k)

    def normal_limit(self, n_points: int) -> float:
        """The normal limit ``c`` of a cloud of ``n_points`` (clamped to the knots; 1: none)."""
        if not self.normal_cos:
            return 1.0
        return float(np.interp(np.log10(n_points), self.bias_log10_points, self.normal_cos))

    def network_weight(
        self, z_score: float, n_points: int, roughness: float, mesh: bool = False
    ) -> float:
        """The network's weight ``w`` in ``[0, 1]`` for a cloud of this OOD z, size and surface
        roughness; 0 for a mesh (its ring graph alone)."""
        if mesh:
            return 0.0
        a, c_z, c_n, c_r = self.gate
        logit = a + c_z * float(z_score) + c_n * (math.log10(n_points) - 3.0) + c_r * roughness
        return float(1.0 / (1.0 + math.exp(-min(max(logit, -60.0), 60.0))))

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        return {"kind": FUSION_KIND, "format_version": FUSION_FORMAT, **data}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> FusionCalibration:
        if data.get("kind") != FUSION_KIND or data.get("format_version") not in READABLE_FORMATS:
            raise ArtifactError(
                f"{FUSION_CONFIG} is not a graph fusion of format {READABLE_FORMATS}; fit it again "
                "(scripts/calibrate_fusion.py)"
            )
        try:
            return cls(
                k=int(data["k"]),
                prune_ratio=float(data["prune_ratio"]),
                bias_log10_points=tuple(float(v) for v in data["bias_log10_points"]),
                bias=tuple(float(v) for v in data["bias"]),
                gate=tuple(float(v) for v in data["gate"]),  # type: ignore[arg-type]
                mesh_bias=float(data["mesh_bias"]),
                bundle_hash=str(data["bundle_hash"]),
                fitted_on=dict(data.get("fitted_on") or {}),
                veto_head=str(data["veto_head"]),
                normal_cos=tuple(float(v) for v in data.get("normal_cos", ())),
                mutual_k=int(data.get("mutual_k", 0)),
                veto_max_z=None if data.get("veto_max_z") is None else float(data["veto_max_z"]),
                mesh_arcs=_flag(data.get("mesh_arcs", False)),
                mesh_noise_knots=tuple(float(v) for v in data.get("mesh_noise_knots", ())),
                mesh_noise_bias=tuple(float(v) for v in data.get("mesh_noise_bias", ())),
                mesh_cloud_noise=(
                    None
                    if data.get("mesh_cloud_noise") is None
                    else float(data["mesh_cloud_noise"])
                ),
                mesh_smooth_noise=(
                    None
                    if data.get("mesh_smooth_noise") is None
                    else float(data["mesh_smooth_noise"])
                ),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ArtifactError(f"{FUSION_CONFIG} is inconsistent: {exc}") from exc


def _flag(value: Any) -> bool:
    """A JSON boolean (anything else is a damaged file)."""
    if not isinstance(value, bool):
        raise ValueError(f"expected true or false, got {value!r}")
    return value


def save_fusion(directory: str | os.PathLike, calibration: FusionCalibration) -> Path:
    """Write ``calibration`` as ``DIRECTORY/fusion.json`` (atomically); returns the path."""
    path = Path(directory) / FUSION_CONFIG
    path.parent.mkdir(parents=True, exist_ok=True)
    data = calibration.to_json()
    data["created"] = datetime.now(UTC).isoformat(timespec="seconds")
    write_json_atomic(path, data)
    return path


def load_fusion(
    bundle_dir: str | os.PathLike | None, bundle_hash: str, name: str
) -> FusionCalibration:
    """The verified fusion calibration beside a bundle.

    Raises:
        InputError: the bundle has none, or it was fitted for another bundle.
        ArtifactError: a damaged file.
    """
    path = None if bundle_dir is None else Path(bundle_dir) / FUSION_CONFIG
    if path is None or not path.is_file():
        raise InputError(
            f"model {name!r} has no graph-fusion calibration ({FUSION_CONFIG}); fit one with "
            "scripts/calibrate_fusion.py or use fusion='none'"
        )
    calibration = FusionCalibration.from_json(read_json_object(path, f"{FUSION_CONFIG} of {name}"))
    if calibration.bundle_hash != bundle_hash:
        raise InputError(
            f"the graph fusion of {name!r} was fitted for bundle {calibration.bundle_hash[:12]}…, "
            f"not for this bundle ({bundle_hash[:12]}…); fit it again"
        )
    return calibration


def resolve_fusion(
    fusion: str, bundle_dir: str | os.PathLike | None, bundle_hash: str, name: str
) -> FusionCalibration | None:
    """The calibration a predictor's ``fusion`` setting selects: ``None`` for ``"none"``, and
    for ``"auto"`` where the bundle has no ``fusion.json``; else the verified calibration.

    Raises:
        InputError: an unknown setting; ``"graph"`` on a bundle without a calibration; a
            calibration fitted for another bundle (also under ``"auto"``: a stale file beside
            a bundle is an error, not a silent fallback).
        ArtifactError: a damaged file.
    """
    if fusion not in FUSIONS:
        raise InputError(f"fusion must be one of {FUSIONS}, got {fusion!r}")
    present = bundle_dir is not None and (Path(bundle_dir) / FUSION_CONFIG).is_file()
    if fusion == "none" or (fusion == "auto" and not present):
        return None
    return load_fusion(bundle_dir, bundle_hash, name)


class ShapeGraph(NamedTuple):
    """What the fusion reads on one shape (:func:`shape_graph`)."""

    graph: sp.csr_array | LazyVetoGraph
    """``(N, N)`` over every point (a cloud's copies and twins join their node)."""
    roughness: float
    """How rough the surface is: a cloud's :func:`surface_roughness` (an input of the gate), a
    mesh's vertex noise (:func:`mesh_noise`, the input of its bias; 0 where the calibration
    reads none: :func:`kept_mesh_noise`)."""
    n_nodes: int
    """Distinct nodes: the mesh's vertices, or the cloud's points without its copies and twins
    (:func:`~litege_core.engines.graph.graph_nodes`): the ``N`` of the gate and the bias."""
    normals: NDArray | None = None
    """``(N, 3)`` vertex normals a mesh graph's arcs were measured with (free query points join
    it by arcs too), or ``None``: plain chords."""


def shape_graph(
    points: NDArray,
    faces: NDArray | None,
    calibration: FusionCalibration,
    kept: dict[str, Any],
    veto_key: str,
    z_score: float,
) -> ShapeGraph:
    """The graph the fusion reads on one shape, its surface roughness and its node count, kept
    in ``kept``.

    A mesh: its ring graph (:data:`MESH_RINGS`; no shortcut between parts that touch; arcs
    where the calibration's ``mesh_arcs`` says so), its vertex noise
    (:func:`kept_mesh_noise`). A cloud: its k-NN graph,
    normal-pruned where the calibration has normal limits, as a
    :class:`~litege_core.learned.veto_graph.LazyVetoGraph` whose network veto
    :func:`graph_rows` runs on the edges that paths use (the rows equal those of
    :func:`pruned_knn_graph`), or as it is where the calibration keeps the veto off at this
    OOD ``z_score`` (:meth:`FusionCalibration.vetoes`); its roughness from the same 16-NN
    covariance.

    Args:
        points: ``(N, 3)`` float64 canonical points.
        faces: ``(F, 3)`` of a mesh, or ``None``.
        calibration: the fusion's constants.
        kept: the shape's memo (a state's ``_lazy``): keys ``fusion.mesh_graph.ARCS``,
            ``fusion.mesh_normals`` (:func:`~litege_core.engines.graph.arc_normals`),
            ``fusion.mesh_noise`` (:func:`mesh_noise`),
            ``fusion.surface``, ``fusion.nodes``
            (:func:`~litege_core.engines.graph.graph_nodes`) and
            :func:`cloud_graph_key`.
        veto_key: names the veto head (its verdicts are kept in the graph).
        z_score: the shape's OOD z-score.
    """
    if faces is not None:
        vertices, smoothed = kept_graph_mesh(points, faces, calibration, kept)
        arcs, suffix = calibration.mesh_arcs, f".{smoothed}" if smoothed else ""
        normals = kept_arc_normals(vertices, faces, kept, suffix) if arcs else None
        key = f"fusion.mesh_graph.{arcs}{suffix}"
        if key not in kept:
            from litege_core.engines.graph import mesh_ring_graph  # scipy: on use

            kept[key] = mesh_ring_graph(vertices, faces, MESH_RINGS, normals=normals)
        noise = kept_mesh_noise(points, faces, calibration, kept)
        return ShapeGraph(kept[key], noise, points.shape[0], normals)
    k, ratio, mutual = calibration.k, calibration.prune_ratio, calibration.mutual_k
    vetoed = calibration.vetoes(z_score)
    key = cloud_graph_key(calibration, veto_key, points.shape[0], vetoed)
    graph, surface, nodes = kept.get(key), kept.get("fusion.surface"), kept.get("fusion.nodes")
    if graph is None or surface is None or nodes is None:  # one search serves all (k = 16)
        from litege_core.engines.graph import (  # scipy: on first use
            graph_nodes,
            knn_neighbours,
            with_copies,
        )

        if nodes is None:
            nodes, neighbours = graph_nodes(points, calibration.reach)
            kept["fusion.nodes"] = nodes
        else:
            neighbours = knn_neighbours(points[nodes[1]], calibration.reach)
        first, index = nodes
        merged = index.size < points.shape[0]
        base = points[index] if merged else points
        if surface is None:
            shared = calibration.reach >= ROUGHNESS_NEIGHBOURS  # the shipped calibrations
            flatness, normals = local_surface(base, nearest=neighbours[1] if shared else None)
            surface = kept["fusion.surface"] = (float(np.median(flatness)), normals)
        if graph is None:
            normal_cos = calibration.normal_limit(index.size)
            unvetoed = pruned_knn_graph(
                base, k, ratio, None, neighbours, surface[1], normal_cos, mutual
            )
            if merged:
                unvetoed = with_copies(unvetoed, points, index, first)
            graph = kept[key] = LazyVetoGraph(unvetoed, ratio) if vetoed else unvetoed
    return ShapeGraph(graph, surface[0], int(nodes[1].size))


def kept_arc_normals(
    points: NDArray, faces: NDArray, kept: dict[str, Any], suffix: str = ""
) -> NDArray | None:
    """A mesh's :func:`~litege_core.engines.graph.arc_normals`, kept in ``kept`` as
    ``fusion.mesh_normals`` + ``suffix`` (its arcs and its vertex noise read the same normals;
    ``suffix`` names smoothed vertices, :func:`kept_graph_mesh`)."""
    key = f"fusion.mesh_normals{suffix}"
    if key not in kept:
        from litege_core.engines.graph import arc_normals  # scipy: on use

        kept[key] = arc_normals(points, faces)
    return kept[key]


def kept_mesh_noise(
    points: NDArray, faces: NDArray, calibration: FusionCalibration, kept: dict[str, Any]
) -> float:
    """A mesh's vertex noise (:func:`mesh_noise`, kept in ``kept`` as ``fusion.mesh_noise``)
    where the calibration reads it (noise knots, a cloud or a smoothing limit), else 0."""
    reads = calibration.mesh_noise_knots or calibration.mesh_cloud_noise is not None
    if not (reads or calibration.mesh_smooth_noise is not None):
        return 0.0
    if "fusion.mesh_noise" not in kept:
        normals = kept_arc_normals(points, faces, kept)
        kept["fusion.mesh_noise"] = mesh_noise(points, faces, normals)
    return float(kept["fusion.mesh_noise"])


def kept_graph_mesh(
    points: NDArray, faces: NDArray, calibration: FusionCalibration, kept: dict[str, Any]
) -> tuple[NDArray, float | None]:
    """The ``(N, 3)`` vertices a mesh's ring graph is built on and the smoothing limit they
    were taken to, or the mesh's own ``points`` and ``None``. A mesh noisier than the
    calibration's ``mesh_smooth_noise`` (:func:`kept_mesh_noise`) is smoothed down to it
    (:func:`~litege_core.learned.mesh_noise.denoised_mesh`, kept in ``kept`` as
    ``fusion.mesh_denoised.LIMIT``)."""
    limit = calibration.mesh_smooth_noise
    if limit is None:
        return points, None
    noise = kept_mesh_noise(points, faces, calibration, kept)
    if noise <= limit:
        return points, None
    key = f"fusion.mesh_denoised.{limit}"
    if key not in kept:
        kept[key] = denoised_mesh(points, faces, limit, noise)
    return kept[key].points, limit


def graph_faces(
    points: NDArray, faces: NDArray | None, calibration: FusionCalibration, kept: dict[str, Any]
) -> NDArray | None:
    """The faces the fusion's graph follows: a mesh's own, or ``None`` (the cloud of its
    vertices) where its vertex noise is above the calibration's cloud limit
    (:meth:`FusionCalibration.answers_as_cloud`); ``None`` for a cloud."""
    if faces is None or calibration.mesh_cloud_noise is None:
        return faces
    noise = kept_mesh_noise(points, faces, calibration, kept)
    return None if calibration.answers_as_cloud(noise) else faces


def cloud_graph_key(
    calibration: FusionCalibration, veto_key: str, n_points: int, vetoed: bool
) -> str:
    """The memo key of a cloud's fusion graph (:func:`shape_graph`): everything that shapes
    it (the veto head and threshold, or no veto; ``k``, the normal limit at ``n_points`` and
    the neighbour rule), so predictors with other calibrations sharing a state keep apart."""
    c = calibration
    veto = f"{veto_key}.{c.prune_ratio}" if vetoed else "unvetoed"
    return f"fusion.graph.{veto}.{c.k}.{c.normal_limit(n_points)}.{c.mutual_k}"


def fused_distances(
    network: Callable[[], NDArray],
    calibration: FusionCalibration,
    points: NDArray,
    faces: NDArray | None,
    src: tuple[NDArray | None, NDArray],
    dst: tuple[NDArray | None, NDArray],
    ood_score: float,
    kept: dict[str, Any],
    edge_geodesics: EdgeGeodesics,
    veto_key: str,
) -> NDArray:
    """The network's distances ``(S, T)`` (canonical units) blended with the graph distances of
    the query points: :func:`shape_graph`, :func:`graph_rows`, then :func:`fuse`; float64
    ``(S, T)``. ``network`` computes them when the answer needs them: on a cloud, and on a mesh
    only where its graph joins no path (a mesh is answered by its graph alone).

    ``src``, ``dst``: ``(indices, canonical)`` as :func:`graph_rows`; ``points``, ``faces``,
    ``kept``, ``edge_geodesics``, ``veto_key``: as :func:`shape_graph` (``kept`` also keeps a
    KD-tree of ``points``, ``fusion.tree``, when free points join). A mesh noisier than the
    calibration's cloud limit is answered as the cloud of its vertices (:func:`graph_faces`)."""
    faces = graph_faces(points, faces, calibration, kept)
    graph, roughness, n_nodes, normals = shape_graph(
        points, faces, calibration, kept, veto_key, ood_score
    )
    tree = None
    if src[0] is None or dst[0] is None:  # free points join through a KD-tree
        tree = kept.get("fusion.tree")
        if tree is None:
            from scipy.spatial import cKDTree

            tree = kept["fusion.tree"] = cKDTree(points)
    rows = graph_rows(graph, points, src, dst, calibration.k, tree, edge_geodesics, normals)
    mesh = faces is not None
    if mesh and np.isfinite(rows).all():  # the network's weight on a mesh is 0
        return rows / calibration.graph_bias(points.shape[0], mesh=True, noise=roughness)
    return fuse(network(), rows, calibration, ood_score, n_nodes, roughness, mesh)


def route_trees(
    graph: LazyVetoGraph, roots: NDArray, far: NDArray, edge_geodesics: EdgeGeodesics
) -> NDArray:
    """Dijkstra predecessors ``(R, N)`` from ``roots`` on the fully vetoed cloud graph, read
    towards the ``far`` nodes: rounds of Dijkstra on ``graph`` judging only the edges of the
    routes from every root to every far node (their trees beyond
    :data:`~litege_core.learned.veto_graph.PATH_PAIRS` pairs), until no route crosses a cut
    edge, as :func:`graph_rows` does (module doc of :mod:`~litege_core.learned.veto_graph`):
    the routes of the fully vetoed graph. ``-9999``: no predecessor (a root, or cut off)."""
    from litege_core.engines.graph import dijkstra_tree  # scipy: on first use

    roots = np.asarray(roots, dtype=np.int64)
    far = np.asarray(far, dtype=np.int64)
    n = graph.graph.shape[0]
    for _ in range(MAX_ROUNDS):
        predecessors = dijkstra_tree(graph.graph, roots)[1]
        if not graph.judge(graph.positions(*path_edges(predecessors, far, n)), edge_geodesics):
            return predecessors
    return dijkstra_tree(graph.vetoed(edge_geodesics), roots)[1]


def pruned_knn_graph(
    points: NDArray,
    k: int,
    prune_ratio: float,
    edge_geodesics: EdgeGeodesics | None,
    neighbours: tuple[NDArray, NDArray] | None = None,
    normals: NDArray | None = None,
    normal_cos: float = 1.0,
    mutual_k: int = 0,
) -> sp.csr_array:
    """The symmetric k-NN graph of ``points`` (with ``mutual_k``: the mutual k-NN graph of that
    many neighbours) without the edges the network calls shortcuts and, with ``normals``,
    without the chords that run along the surface normal. With
    ``edge_geodesics`` it is the eager reference of the lazy veto of :func:`graph_rows` (which
    the fusion runs); without, the graph that veto starts from.

    Args:
        points: ``(N, 3)`` float64 (canonical frame).
        k: neighbours per point (clamped to ``N - 1``).
        prune_ratio: cut an edge whose predicted geodesic exceeds ``prune_ratio`` × its chord.
        edge_geodesics: predicted geodesics of ``(i, j)`` pairs, or ``None`` (no pruning).
        neighbours: :func:`~litege_core.engines.graph.knn_neighbours` of ``points`` for
            ``k`` or more, if already known.
        normals: ``(N, 3)`` unit normals (any sign, :func:`local_surface`), or ``None``.
        normal_cos: cut an edge whose unit chord ``ĉ`` has ``|n · ĉ| > normal_cos`` at either
            end (1: keep every edge).
        mutual_k: 0: the symmetric k-NN graph; else the mutual k-NN graph of ``mutual_k``
            neighbours (``neighbours`` then covers ``mutual_k`` or more).

    Returns:
        ``(N, N)`` upper-triangular CSR of chord lengths (:func:`~litege_core.engines.graph.
        edge_graph`).
    """
    import scipy.sparse as sp

    from litege_core.engines.graph import knn_graph, knn_neighbours, mutual_knn_graph

    if neighbours is None:  # the plain lists (the fusion passes its nodes': shape_graph)
        neighbours = knn_neighbours(points, max(k, mutual_k))
    if mutual_k:
        graph = mutual_knn_graph(points, mutual_k, neighbours)
    else:
        graph = knn_graph(points, k, neighbours)
    cut_normals = normals is not None and normal_cos < 1.0
    if (edge_geodesics is None and not cut_normals) or graph.nnz == 0:
        return graph
    rows = np.repeat(np.arange(graph.shape[0]), np.diff(graph.indptr))  # CSR order
    keep = np.ones(graph.nnz, dtype=bool)
    if cut_normals:
        assert normals is not None
        keep &= normal_cosines(points, normals, rows, graph.indices, graph.data) <= normal_cos
    if edge_geodesics is not None:  # the network only on the edges the normals leave
        left = np.flatnonzero(keep)
        keep[left] = edge_geodesics(rows[left], graph.indices[left]) <= (
            prune_ratio * graph.data[left]
        )
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows[keep], minlength=graph.shape[0]))])
    return sp.csr_array((graph.data[keep], graph.indices[keep], indptr), shape=graph.shape)


def normal_cosines(
    points: NDArray, normals: NDArray, starts: NDArray, ends: NDArray, lengths: NDArray
) -> NDArray:
    """``(E,)`` how far each chord runs along the surface normal: ``|n · ĉ|`` at the end where it
    is larger, ``ĉ`` the unit chord (0 for a zero chord).

    Args:
        points: ``(N, 3)`` float64; normals: ``(N, 3)`` unit normals (any sign).
        starts, ends: ``(E,)`` the chords' end points; lengths: ``(E,)`` their lengths.
    """
    axes, normal_axes = np.ascontiguousarray(points.T), np.ascontiguousarray(normals.T)
    chords = np.take(axes, ends, axis=1) - np.take(axes, starts, axis=1)  # (3, E)
    chords /= np.maximum(lengths, 1e-300)  # zero chords: cosines 0
    return np.maximum(
        np.abs(np.einsum("ie,ie->e", np.take(normal_axes, starts, axis=1), chords)),
        np.abs(np.einsum("ie,ie->e", np.take(normal_axes, ends, axis=1), chords)),
    )


def graph_rows(
    graph: sp.csr_array | LazyVetoGraph,
    points: NDArray,
    src: tuple[NDArray | None, NDArray],
    dst: tuple[NDArray | None, NDArray],
    k: int,
    tree: Any = None,
    edge_geodesics: EdgeGeodesics | None = None,
    normals: NDArray | None = None,
) -> NDArray:
    """``(S, T)`` graph distances between query points (``inf`` where no path joins them).

    A query is ``(indices, canonical)``: its node indices, or ``None`` with its ``(Q, 3)``
    canonical coordinates for points that are not nodes. Such a free point joins the graph
    through chords to its ``k`` nearest points, and only as an end of its own paths: no path
    passes through another query point, so a row does not depend on what else a request asks
    (a request split into blocks gets the same answers). With a mesh graph's arc ``normals``
    (:class:`ShapeGraph`), those chords are arcs too, measured with the normal of the free
    point's nearest vertex: a point on a vertex is answered as that vertex. Dijkstra runs from
    the smaller side.
    ``tree``: a ``scipy.spatial.cKDTree`` of ``points`` if the caller keeps one (built here
    otherwise). The cached ``graph`` is never changed.

    A :class:`~litege_core.learned.veto_graph.LazyVetoGraph` is judged by ``edge_geodesics``
    on the edges of the paths the query reads, round after round, until no path crosses a
    cut edge (its module docstring): the rows of the fully vetoed graph, exactly.
    """
    if not isinstance(graph, LazyVetoGraph):
        return _graph_rows(graph, points, src, dst, k, tree, paths=False, normals=normals)[0]
    if edge_geodesics is None:
        raise InputError("a lazily vetoed graph needs the veto's edge geodesics")
    n = points.shape[0]
    sizes = [q[1].shape[0] if q[0] is None else distinct_indices(q[0], n).size for q in (src, dst)]
    if min(sizes) <= LAZY_SOURCES:  # the Dijkstra runs of a round are few: judge lazily
        for _ in range(MAX_ROUNDS):
            rows, read = _graph_rows(graph.graph, points, src, dst, k, tree, paths=True)
            assert read is not None
            predecessors, far = read
            positions = graph.positions(*path_edges(predecessors, far, n))
            if not graph.judge(positions, edge_geodesics):
                return rows
            if reads_trees(predecessors.shape[0], far.size):  # where the trees re-route
                graph.judge_below_cuts(predecessors, positions, edge_geodesics)
    final = graph.vetoed(edge_geodesics)
    return _graph_rows(final, points, src, dst, k, tree, paths=False)[0]


def _graph_rows(
    graph: sp.csr_array,
    points: NDArray,
    src: tuple[NDArray | None, NDArray],
    dst: tuple[NDArray | None, NDArray],
    k: int,
    tree: Any,
    paths: bool,
    normals: NDArray | None = None,
) -> tuple[NDArray, tuple[NDArray, NDArray] | None]:
    """:func:`graph_rows` on a plain graph; with ``paths``, also what its shortest paths
    are read from: the ``(U, M)`` Dijkstra predecessors and the ``(F,)`` far node ids
    (:func:`~litege_core.learned.veto_graph.path_edges`)."""
    from litege_core.engines.graph import dijkstra_rows, dijkstra_tree

    count = [q[1].shape[0] if q[0] is None else np.asarray(q[0]).size for q in (src, dst)]
    flip = count[0] > count[1]  # Dijkstra from the smaller side
    near, far = (dst, src) if flip else (src, dst)
    directed = not (near[0] is not None and far[0] is not None)
    if directed:  # free points: the directed graph of _with_free_points
        graph, near_ids, far_ids = _with_free_points(graph, points, near, far, k, tree, normals)
    else:  # nodes only: the graph as it is
        near_ids, far_ids = (np.asarray(q[0], dtype=np.int64) for q in (near, far))
    unique, order = np.unique(near_ids, return_inverse=True)
    read = None
    if paths:
        full, predecessors = dijkstra_tree(graph, unique, directed=directed)
        read = predecessors, far_ids
    else:
        full = dijkstra_rows(graph, unique, directed=directed)
    rows = full[order.reshape(-1)][:, far_ids]
    return (rows.T if flip else rows), read


def _with_free_points(
    graph: sp.csr_array,
    points: NDArray,
    near: tuple[NDArray | None, NDArray],
    far: tuple[NDArray | None, NDArray],
    k: int,
    tree: Any,
    normals: NDArray | None = None,
) -> tuple[sp.csr_array, NDArray, NDArray]:
    """The directed graph of :func:`graph_rows` with free query points, and the node ids of the
    ``near`` and ``far`` queries in it (chords lengthened to arcs with ``normals``, each free
    point taking its nearest point's).

    ``graph`` (upper-triangular ``(n, n)`` CSR, as :func:`~litege_core.engines.graph.edge_graph`
    builds it) becomes both directions of every edge; each free ``near`` point a new node with
    chords *out* to its ``k`` nearest points, each free ``far`` point one with chords *in* from
    them. Paths from near nodes then end at far nodes and never pass through a query point.
    Explicit zero lengths stay edges."""
    import scipy.sparse as sp

    n = points.shape[0]
    coo = graph.tocoo()
    rows, cols, lengths = [coo.row, coo.col], [coo.col, coo.row], [coo.data, coo.data]
    ids: list[NDArray] = []
    n_free = 0
    for side, (indices, canonical) in (("near", near), ("far", far)):
        if indices is not None:
            ids.append(np.asarray(indices, dtype=np.int64))
            continue
        if tree is None:
            from scipy.spatial import cKDTree

            tree = cKDTree(points)
        neighbours = min(k, n)
        chords, nearest = tree.query(canonical, k=neighbours)
        chords = chords.reshape(len(canonical), neighbours).reshape(-1)
        nearest = nearest.reshape(len(canonical), neighbours).reshape(-1)
        if normals is not None:
            from litege_core.engines.graph import arc_factors

            own = np.repeat(nearest.reshape(len(canonical), neighbours)[:, 0], neighbours)
            chords = chords * arc_factors(normals[own], normals[nearest])
        nodes = n + n_free + np.arange(len(canonical))
        n_free += len(canonical)
        free = np.repeat(nodes, neighbours)
        rows.append(free if side == "near" else nearest)
        cols.append(nearest if side == "near" else free)
        lengths.append(chords)
        ids.append(nodes)
    size = n + n_free
    augmented = sp.csr_array(
        (np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size)
    )
    return augmented, ids[0], ids[1]


def local_surface(
    points: NDArray, k: int = ROUGHNESS_NEIGHBOURS, nearest: NDArray | None = None
) -> tuple[NDArray, NDArray]:
    """Each point's neighbourhood shape from the covariance of its ``k`` nearest points
    (itself included): ``(N,)`` ``sqrt(λ_min / λ_max)`` (flatness; scale-free) and ``(N, 3)``
    unit normals (the ``λ_min`` eigenvector, unoriented).

    ``points``: ``(N, 3)`` float64; ``nearest``: the indices of
    :func:`~litege_core.engines.graph.knn_neighbours` ``(points, k)`` if already known. Fewer
    than 4 points: ratios 0 and normals 0.
    """
    from litege_core.engines.graph import knn_neighbours

    n = points.shape[0]
    count = min(k, n)
    ratios, normals = np.zeros(n), np.zeros((n, 3))
    if count < 4:
        return ratios, normals
    if nearest is None:  # the same search as a k = 16 fusion graph's: same ties, same answer
        nearest = knn_neighbours(points, k)[1]
    axes = np.ascontiguousarray(points.T)  # (3, N): np.take along rows beats fancy indexing
    for start in range(0, n, ROUGHNESS_CHUNK):
        block = np.ascontiguousarray(nearest[start : start + ROUGHNESS_CHUNK, :count].T)
        local = np.take(axes, block, axis=1)  # (3, k, C): sums over k run along C
        local -= local.mean(axis=1, keepdims=True)
        covariance = np.einsum("ikc,jkc->cij", local, local)  # (C, 3, 3)
        smallest, largest, normal = _extreme_eigenpairs(covariance)
        ratios[start : start + ROUGHNESS_CHUNK] = np.sqrt(
            np.clip(smallest, 0.0, None) / np.maximum(largest, 1e-300)
        )
        normals[start : start + ROUGHNESS_CHUNK] = normal
    return ratios, normals


def _extreme_eigenpairs(matrices: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """The smallest and largest eigenvalues ``(C,)`` of symmetric ``(C, 3, 3)`` matrices and a
    unit eigenvector ``(C, 3)`` of the smallest, in closed form (~30x faster than batched
    ``numpy.linalg.eigh``, which :func:`_extreme_eigenpairs_reference` calls).

    Eigenvalues by the trigonometric solution of the characteristic cubic; the eigenvector as
    the longest cross product of two rows of ``A − λ_min I`` (they span the plane orthogonal
    to it). Where that is not well defined (a repeated smallest eigenvalue: points on a line,
    or all at one spot) the row falls back to ``eigh``, whose choice is as good as any. All on
    ``(C,)`` arrays of the six distinct entries (no small-axis operations)."""
    xx, yy, zz = matrices[:, 0, 0], matrices[:, 1, 1], matrices[:, 2, 2]
    xy, xz, yz = matrices[:, 0, 1], matrices[:, 0, 2], matrices[:, 1, 2]
    q = (xx + yy + zz) / 3.0
    off = xy**2 + xz**2 + yz**2
    p = np.sqrt(((xx - q) ** 2 + (yy - q) ** 2 + (zz - q) ** 2 + 2.0 * off) / 6.0)
    scale = np.maximum(p, 1e-300)  # B = (A − qI) / p: its determinant by cofactors
    bxx, byy, bzz, bxy, bxz, byz = (v / scale for v in (xx - q, yy - q, zz - q, xy, xz, yz))
    det = bxx * (byy * bzz - byz * byz) - bxy * (bxy * bzz - byz * bxz)
    det += bxz * (bxy * byz - byy * bxz)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    largest = q + 2.0 * p * np.cos(phi)
    smallest = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    rows = (xx - smallest, xy, xz), (xy, yy - smallest, yz), (xz, yz, zz - smallest)
    crosses = np.stack(
        [_cross(rows[0], rows[1]), _cross(rows[0], rows[2]), _cross(rows[1], rows[2])]
    )  # (3 crosses, 3, C)
    lengths = np.sqrt(np.einsum("xic,xic->xc", crosses, crosses))  # (3, C)
    best = np.argmax(lengths, axis=0)
    index = np.arange(matrices.shape[0])
    longest = lengths[best, index]
    normal = crosses[best, :, index] / np.maximum(longest, 1e-300)[:, None]  # (C, 3)
    # a repeated smallest eigenvalue: the cross products vanish against the spread squared
    loose = longest <= 1e-6 * np.maximum(largest - smallest, 1e-300) ** 2
    if np.any(loose):
        _, _, normal[loose] = _extreme_eigenpairs_reference(matrices[loose])
    return smallest, largest, normal


def _cross(
    a: tuple[NDArray, NDArray, NDArray], b: tuple[NDArray, NDArray, NDArray]
) -> tuple[NDArray, NDArray, NDArray]:
    """The cross product ``a × b`` of vectors given as three ``(C,)`` component arrays."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _extreme_eigenpairs_reference(matrices: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`_extreme_eigenpairs` by ``numpy.linalg.eigh`` (the slow reference)."""
    eigenvalues, eigenvectors = np.linalg.eigh(matrices)  # ascending
    return eigenvalues[:, 0], eigenvalues[:, 2], eigenvectors[:, :, 0]


def surface_roughness(
    points: NDArray, k: int = ROUGHNESS_NEIGHBOURS, nearest: NDArray | None = None
) -> float:
    """How far the points are from a smooth surface: the median over points of
    ``sqrt(λ_min / λ_max)`` of :func:`local_surface`.

    Scale-free, ~0.05–0.15 on clean surface samples (curvature within a neighbourhood),
    higher with noise. ``points``: ``(N, 3)`` float64; ``nearest``: as :func:`local_surface`.
    """
    return float(np.median(local_surface(points, k, nearest)[0]))


def fuse(
    network: NDArray,
    graph: NDArray,
    calibration: FusionCalibration,
    z_score: float,
    n: int,
    roughness: float,
    mesh: bool = False,
) -> NDArray:
    """``w · network + (1 − w) · graph / b`` (same units; ``mesh``: the graph is the mesh's
    ring graph); the network alone where the graph is ``inf``. ``network``, ``graph``: ``(S, T)``;
    ``roughness``: as :class:`ShapeGraph`'s; returns float64 ``(S, T)``."""
    weight = calibration.network_weight(z_score, n, roughness, mesh)
    network = np.asarray(network, np.float64)
    corrected = corrected_graph(network, graph, calibration, n, mesh, roughness)
    return weight * network + (1.0 - weight) * corrected


def corrected_graph(
    network: NDArray,
    graph: NDArray,
    calibration: FusionCalibration,
    n: int,
    mesh: bool = False,
    roughness: float = 0.0,
) -> NDArray:
    """``graph / b`` as :func:`fuse` blends it: the network's value where the graph is ``inf``.
    ``network``, ``graph``: ``(S, T)`` (same units); ``roughness``: a mesh's vertex noise
    (:func:`mesh_noise`; a cloud's bias ignores it); returns float64 ``(S, T)``."""
    corrected = np.asarray(graph, np.float64) / calibration.graph_bias(n, mesh, roughness)
    return np.where(np.isfinite(corrected), corrected, np.asarray(network, np.float64))


__all__ = [
    "DEFAULT_FUSION",
    "FUSIONS",
    "FUSION_CONFIG",
    "MESH_RINGS",
    "FusionCalibration",
    "ShapeGraph",
    "cloud_graph_key",
    "corrected_graph",
    "fuse",
    "fused_distances",
    "graph_faces",
    "graph_rows",
    "kept_arc_normals",
    "kept_graph_mesh",
    "kept_mesh_noise",
    "load_fusion",
    "local_surface",
    "normal_cosines",
    "pruned_knn_graph",
    "resolve_fusion",
    "route_trees",
    "save_fusion",
    "shape_graph",
    "surface_roughness",
]
