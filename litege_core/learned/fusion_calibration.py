"""The graph fusion's calibration: the constants :mod:`~litege_core.learned.fusion` blends the
network and the graph with, fitted on data we generate (``scripts/calibrate_fusion.py``) and
kept beside the bundle as ``fusion.json`` (:func:`save_fusion`, :func:`load_fusion`,
:func:`resolve_fusion`: a file fitted for another bundle is refused)."""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from litege_core.errors import ArtifactError, InputError
from litege_core.files import read_json_object, write_json_atomic

FUSION_CONFIG = "fusion.json"
FUSION_KIND = "graph_fusion"
FUSION_FORMAT = 11
"""Format 3 added ``mesh_bias`` and ``mesh_gate`` (meshes use their own connectivity), format 4
``normal_cos`` (a format-3 file reads as one without normal limits), format 5 dropped
``mesh_gate`` (a mesh is answered by its graph alone; older files' gate is ignored), format 6
added ``mutual_k`` (older files read as 0: the symmetric k-NN graph), format 7
``veto_max_z`` (older files read as ``None``: the veto on every cloud), format 8
``mesh_arcs`` (older files read as ``False``: plain chords), format 9 ``mesh_noise_knots``,
``mesh_noise_bias`` (older files read as empty: ``mesh_bias`` at every noise) and
``mesh_cloud_noise`` (older files read as ``None``: every mesh its ring graph), format 10
``mesh_smooth_noise`` (older files read as ``None``: every mesh's ring graph on its own
vertices), format 11 ``shortcut_cut``, ``shortcut_scorer`` and ``shortcut_max_roughness``
(older files read as no cut)."""
READABLE_FORMATS = (3, 4, 5, 6, 7, 8, 9, 10, FUSION_FORMAT)

FUSIONS = ("auto", "none", "graph")
"""Values of the predictors' ``fusion``: ``auto`` (the default: ``graph`` where the bundle ships
a calibration, else ``none``), ``none`` (the network alone) or ``graph``."""
DEFAULT_FUSION = "auto"
VETO_HEADS = ("full", "small")


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
        mesh_noise_knots: increasing knots of a mesh's vertex noise
            (:func:`~litege_core.learned.mesh_noise.mesh_noise`), or empty: ``mesh_bias``
            whatever the noise.
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
        shortcut_cut: per bias knot, the probability above which the learned shortcut scorer
            (:mod:`~litege_core.learned.shortcuts`) cuts a cloud edge (1: no cut), or empty:
            no scorer.
        shortcut_scorer: the sha256 of that scorer's weights (the shipped one must match).
        shortcut_max_roughness: the scorer cuts only clouds whose roughness is at most this
            (noisy clouds read as full of shortcuts); ``None``: any cloud.
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
    shortcut_cut: tuple[float, ...] = ()
    shortcut_scorer: str = ""
    shortcut_max_roughness: float | None = None

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
        cuts = np.asarray(self.shortcut_cut, dtype=np.float64)
        if cuts.size and not (cuts.shape == knots.shape and np.all((cuts > 0) & (cuts <= 1))):
            raise ArtifactError("fusion shortcut_cut must be empty or one value in (0, 1] per knot")
        if cuts.size and not self.shortcut_scorer:
            raise ArtifactError("fusion shortcut_cut needs the sha256 of its shortcut_scorer")
        rough = self.shortcut_max_roughness
        if rough is not None and not (math.isfinite(rough) and rough > 0):
            raise ArtifactError(f"fusion shortcut_max_roughness must be positive, got {rough!r}")
        if self.veto_max_z is not None and not math.isfinite(self.veto_max_z):
            raise ArtifactError(
                f"fusion veto_max_z must be finite or None, got {self.veto_max_z!r}"
            )

    def vetoes(self, z_score: float) -> bool:
        """Whether the network vetoes the graph edges of a cloud of this OOD z-score: always
        without ``veto_max_z``, else where ``z_score <= veto_max_z`` (never for a ``nan``)."""
        return self.veto_max_z is None or float(z_score) <= self.veto_max_z

    def answers_as_cloud(self, noise: float) -> bool:
        """Whether a mesh of this vertex noise
        (:func:`~litege_core.learned.mesh_noise.mesh_noise`) is answered as the cloud of its
        vertices (above ``mesh_cloud_noise``), not by its ring graph."""
        return self.mesh_cloud_noise is not None and noise > self.mesh_cloud_noise

    def graph_bias(self, n_points: int, mesh: bool = False, noise: float = 0.0) -> float:
        """The graph's over-estimate factor: on a mesh of vertex ``noise``
        (:func:`~litege_core.learned.mesh_noise.mesh_noise`) interpolated in the noise knots
        (the first knot's below them, the last segment extended beyond them; ``mesh_bias``
        without knots), else at ``n_points`` cloud points (clamped to the knots)."""
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

    def shortcut_limit(self, n_points: int, roughness: float) -> float:
        """The shortcut scorer's cut for a cloud of ``n_points`` and this roughness (clamped
        to the knots; 1: no cut, also above ``shortcut_max_roughness``)."""
        if not self.shortcut_cut:
            return 1.0
        if self.shortcut_max_roughness is not None and roughness > self.shortcut_max_roughness:
            return 1.0
        return float(np.interp(np.log10(n_points), self.bias_log10_points, self.shortcut_cut))

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
                shortcut_cut=tuple(float(v) for v in data.get("shortcut_cut", ())),
                shortcut_scorer=str(data.get("shortcut_scorer", "")),
                shortcut_max_roughness=(
                    None
                    if data.get("shortcut_max_roughness") is None
                    else float(data["shortcut_max_roughness"])
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


__all__ = [
    "DEFAULT_FUSION",
    "FUSIONS",
    "FUSION_CONFIG",
    "FUSION_FORMAT",
    "FUSION_KIND",
    "READABLE_FORMATS",
    "VETO_HEADS",
    "FusionCalibration",
    "load_fusion",
    "resolve_fusion",
    "save_fusion",
]
