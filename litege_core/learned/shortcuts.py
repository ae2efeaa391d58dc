"""A learned scorer of a cloud graph's shortcuts: edges between parts that touch in space (a leg
tucked against the belly, an arm at the side) or through thin parts, whose true geodesic is many
times their chord (issue 14). The fusion cuts the edges it scores above its calibration's
threshold before its Dijkstra (:func:`~litege_core.learned.fusion.shape_graph`).

The scorer reads only local geometry, so one scorer serves every bundle:

* each point's ``K`` nearest neighbours in its own tangent frame, as scale-free inputs
  (:func:`neighbour_inputs`: in-plane radius and height over the cloud's spacing, and how far
  the two normals agree) go through a shared point MLP, max-pooled, once for each side of the
  unoriented normal (and their mean, for a chord in the tangent plane): ``(N, 3, 2w)``
  embeddings, the head's first layer already applied;
* an edge ``(i, j)`` reads the embedding of each end on the side that faces the other end, plus
  six features of its own (:func:`edge_inputs`), through a small MLP: the logit of being a
  shortcut. Symmetric in ``i`` and ``j`` by construction.

Its weights ship once with the library (:data:`SHIPPED_SCORER_DIR`: ``weights.safetensors`` and
``config.json``, ~25 KB); a fusion calibration that cuts names their sha256
(:attr:`~litege_core.learned.fusion_calibration.FusionCalibration.shortcut_scorer`) and is
refused with any other scorer. Inference is numpy (:class:`ScorerWeights`), so the torch-free
:class:`~litege_core.learned.numpy_predictor.NumpyPredictor` cuts as the predictor does;
``scripts/train_shortcut_scorer.py`` trains it (:mod:`litege_core.train.shortcuts`, torch) on
procedural animals in contact poses (never on the dev set).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from litege_core.errors import ArtifactError, InputError
from litege_core.files import file_sha256, read_json_object, write_json_atomic

SCORER_KIND = "shortcut_scorer"
SCORER_FORMAT = 1
SCORER_WEIGHTS = "weights.safetensors"
SCORER_CONFIG = "config.json"
SHIPPED_SCORER_DIR = Path(__file__).resolve().parent.parent / "models" / "shortcut-scorer"
"""Where the library's scorer ships (no bundle manifest: not a geodesic or matching bundle)."""
NEIGHBOURS = 16
"""Nearest points per embedding (``K``)."""
N_NEIGHBOUR_INPUTS = 3
N_EDGE_INPUTS = 6
SPACING_RANK = 8
"""A cloud's spacing: the median distance to each point's 8th nearest point (as the
diagnoses' :class:`~litege_core.evaluation.cloud_edges.KeptEdges`)."""
TANGENT_COSINE = 1e-9
"""A chord whose ``|n · ĉ|`` is at most this lies in the end's tangent plane (side 2)."""


@dataclass(frozen=True)
class ScorerWeights:
    """The scorer's float32 weights (the names and shapes of the training module's
    ``state_dict``, :class:`~litege_core.train.shortcuts.ShortcutScorer`): a point MLP
    ``3 → w → 2w`` (``point_1``, ``point_2``), the edge head's first layer split into its
    ends' part (``ends``, no bias) and its features' (``edge``), then ``2w → w → 1``
    (``head_1``, ``head_2``). Matrices are ``(out, in)``."""

    point_1: NDArray
    point_1_bias: NDArray
    point_2: NDArray
    point_2_bias: NDArray
    ends: NDArray
    edge: NDArray
    edge_bias: NDArray
    head_1: NDArray
    head_1_bias: NDArray
    head_2: NDArray
    head_2_bias: NDArray
    neighbours: int = NEIGHBOURS

    @property
    def width(self) -> int:
        return int(self.point_1.shape[0])

    @classmethod
    def from_state(cls, state: Mapping[str, Any], neighbours: int = NEIGHBOURS) -> ScorerWeights:
        """From a ``state_dict`` (tensors or arrays) of the training module.

        Raises:
            ArtifactError: a missing weight or shapes that do not fit together.
        """
        try:
            arrays = {
                field_name: np.ascontiguousarray(np.asarray(state[key], dtype=np.float32))
                for field_name, key in _STATE_KEYS.items()
            }
            weights = cls(**arrays, neighbours=int(neighbours))
        except (KeyError, TypeError, ValueError) as exc:
            raise ArtifactError(f"shortcut scorer weights are inconsistent: {exc}") from exc
        w = weights.width
        expected = {
            "point_1": (w, N_NEIGHBOUR_INPUTS), "point_1_bias": (w,), "point_2": (2 * w, w),
            "point_2_bias": (2 * w,), "ends": (2 * w, 2 * w), "edge": (2 * w, N_EDGE_INPUTS),
            "edge_bias": (2 * w,), "head_1": (w, 2 * w), "head_1_bias": (w,),
            "head_2": (1, w), "head_2_bias": (1,),
        }  # fmt: skip
        for name, shape in expected.items():
            if getattr(weights, name).shape != shape:
                raise ArtifactError(f"shortcut scorer weight {name} is not of shape {shape}")
        if weights.neighbours < 1:
            raise ArtifactError(f"shortcut scorer neighbours must be >= 1, got {neighbours}")
        return weights

    def embed(self, inputs: NDArray) -> NDArray:
        """``(R, K, 3)`` :func:`neighbour_inputs` → ``(R, 3, 2w)`` float32: side 0 sees the
        normal as given, side 1 flipped (the heights negated), side 2 their mean (a chord in
        the tangent plane faces neither side); the edge head's ends layer applied.

        One neighbour rank at a time (a running max: the pooled ``(2R, 2w)`` block stays in
        cache); ``relu(max + b) = max(relu(· + b))`` moves the second bias after the pool."""
        slices = np.ascontiguousarray(inputs.transpose(1, 0, 2))  # (K, R, 3)
        level = slices[..., 0::2] @ self.point_1[:, 0::2].T + self.point_1_bias  # (K, R, w)
        height = slices[..., 1:2] * self.point_1[:, 1]  # the one input a flip negates
        second = np.ascontiguousarray(self.point_2.T)
        pooled = None
        for rank in range(slices.shape[0]):
            hidden = np.concatenate([level[rank] + height[rank], level[rank] - height[rank]])
            np.maximum(hidden, 0.0, out=hidden)  # (2R, w): side 0 then side 1
            out = hidden @ second
            pooled = out if pooled is None else np.maximum(pooled, out, out=pooled)
        assert pooled is not None
        pooled += self.point_2_bias
        np.maximum(pooled, 0.0, out=pooled)
        sides = (pooled @ self.ends.T).reshape(2, -1, 2 * self.width).transpose(1, 0, 2)
        return np.concatenate([sides, sides.mean(axis=1, keepdims=True)], axis=1)

    def logits(
        self,
        embedded: NDArray,
        i: NDArray,
        j: NDArray,
        side_i: NDArray,
        side_j: NDArray,
        features: NDArray,
    ) -> NDArray:
        """``(E,)`` float32 shortcut logits of edges ``(i, j)`` (rows of ``embedded``, the
        sides and ``(E, 6)`` features of :func:`edge_inputs`)."""
        hidden = embedded[i, side_i] + embedded[j, side_j]
        hidden += features @ self.edge.T + self.edge_bias
        np.maximum(hidden, 0.0, out=hidden)
        hidden = hidden @ self.head_1.T + self.head_1_bias
        np.maximum(hidden, 0.0, out=hidden)
        return (hidden @ self.head_2.T + self.head_2_bias)[:, 0]


_STATE_KEYS = {
    "point_1": "point.0.weight", "point_1_bias": "point.0.bias",
    "point_2": "point.2.weight", "point_2_bias": "point.2.bias",
    "ends": "ends.weight", "edge": "edge.weight", "edge_bias": "edge.bias",
    "head_1": "head.1.weight", "head_1_bias": "head.1.bias",
    "head_2": "head.3.weight", "head_2_bias": "head.3.bias",
}  # fmt: skip
""":class:`ScorerWeights` field → the training module's ``state_dict`` key."""


def cloud_spacing(lengths: NDArray) -> float:
    """The spacing of a cloud from its :func:`~litege_core.engines.graph.knn_neighbours`
    distances ``(N, k + 1)`` (itself first, ``k`` ≥ 8): canonical units, at least 1e-12."""
    return max(float(np.median(lengths[:, SPACING_RANK])), 1e-12)


def neighbour_inputs(
    points: NDArray, nearest: NDArray, normals: NDArray, spacing: float, rows: NDArray
) -> NDArray:
    """``(R, K, 3)`` float32 inputs of the point MLP for the points ``rows``: each of the ``K``
    nearest other points' in-plane radius and signed height in the point's tangent frame, over
    ``spacing``, and the two unit normals' ``|n_p · n_q|``.

    Args:
        points: ``(N, 3)``; normals: ``(N, 3)`` unit (any sign; the scorer reads both sides).
        nearest: ``(N, K)`` the nearest other points (without the point itself).
        spacing: :func:`cloud_spacing`.
        rows: ``(R,)`` the points to embed.
    """
    around, centre, normal = nearest[rows], points[rows], normals[rows]
    offsets = (points[around] - centre[:, None, :]) / spacing  # (R, K, 3)
    height = np.einsum("nkc,nc->nk", offsets, normal)
    radius = np.sqrt(np.maximum(np.einsum("nkc,nkc->nk", offsets, offsets) - height**2, 0.0))
    agree = np.abs(np.einsum("nkc,nc->nk", normals[around], normal))
    return np.stack([radius, height, agree], axis=-1).astype(np.float32)


def edge_inputs(
    points: NDArray,
    normals: NDArray,
    flatness: NDArray,
    spacing: float,
    i: NDArray,
    j: NDArray,
) -> tuple[NDArray, NDArray, NDArray]:
    """The side of each end that faces the other end (0: along its normal, 1: against, 2: in
    its tangent plane) and
    ``(E, 6)`` float32 edge features: chord over spacing, the larger and smaller ``|n · ĉ|`` at
    the two ends, the larger and smaller flatness
    (:func:`~litege_core.learned.cloud_surface.local_surface`), and ``|n_i · n_j|``.

    Args:
        points, normals: ``(N, 3)``; flatness: ``(N,)``; spacing: :func:`cloud_spacing`.
        i, j: ``(E,)`` the edges' ends.
    """
    chords = points[j] - points[i]
    lengths = np.linalg.norm(chords, axis=1)
    units = chords / np.maximum(lengths, 1e-12)[:, None]
    cos_i = np.einsum("ec,ec->e", normals[i], units)
    cos_j = -np.einsum("ec,ec->e", normals[j], units)
    side_i, side_j = _side(cos_i), _side(cos_j)
    abs_i, abs_j = np.abs(cos_i), np.abs(cos_j)
    flat_i, flat_j = flatness[i], flatness[j]
    agree = np.abs(np.einsum("ec,ec->e", normals[i], normals[j]))
    features = np.column_stack(
        [
            lengths / spacing,
            np.maximum(abs_i, abs_j),
            np.minimum(abs_i, abs_j),
            np.maximum(flat_i, flat_j),
            np.minimum(flat_i, flat_j),
            agree,
        ]
    )
    return side_i, side_j, features.astype(np.float32)


def _side(cosines: NDArray) -> NDArray:
    """The embedding side an end reads: 0 where the chord runs along its normal, 1 against,
    2 (both sides' mean) where it lies in the tangent plane."""
    side = (cosines < 0).astype(np.int64)
    side[np.abs(cosines) <= TANGENT_COSINE] = 2
    return side


def shortcut_probabilities(
    scorer: ScorerWeights,
    points: NDArray,
    nearest: NDArray,
    spacing: float,
    normals: NDArray,
    flatness: NDArray,
    i: NDArray,
    j: NDArray,
) -> NDArray:
    """``(E,)`` float32: the probability that each edge ``(i, j)`` of a cloud is a shortcut.
    One embedding pass over the points the edges touch (every point when there are at least as
    many edges as points), one batched head pass over the edges.

    Args:
        scorer: the scorer (eval mode, CPU).
        points: ``(N, 3)`` the cloud (canonical frame; any unit: inputs are over ``spacing``).
        nearest: ``(N, ≥ K)`` each point's nearest other points, nearest first.
        spacing: :func:`cloud_spacing`.
        normals: ``(N, 3)`` unit normals; flatness: ``(N,)``
            (:func:`~litege_core.learned.cloud_surface.local_surface`).
        i, j: ``(E,)`` int edge ends.
    """
    if i.size == 0:
        return np.zeros(0, dtype=np.float32)
    if i.size >= points.shape[0]:  # a whole graph's edges: every point is an end, or nearly
        used, inverse = np.arange(points.shape[0]), np.concatenate([i, j])
    else:
        used, inverse = np.unique(np.concatenate([i, j]), return_inverse=True)
    inputs = neighbour_inputs(points, nearest[:, : scorer.neighbours], normals, spacing, used)
    side_i, side_j, features = edge_inputs(points, normals, flatness, spacing, i, j)
    embedded = scorer.embed(inputs)
    logits = scorer.logits(embedded, inverse[: i.size], inverse[i.size :], side_i, side_j, features)
    return (1.0 / (1.0 + np.exp(-np.clip(logits, -60.0, 60.0)))).astype(np.float32)


def shortcut_probabilities_reference(
    scorer: ScorerWeights,
    points: NDArray,
    nearest: NDArray,
    spacing: float,
    normals: NDArray,
    flatness: NDArray,
    i: NDArray,
    j: NDArray,
) -> NDArray:
    """:func:`shortcut_probabilities` one edge and one neighbour at a time, in float64,
    written out from the definitions (tests)."""

    def relu(x: NDArray) -> NDArray:
        return np.maximum(x, 0.0)

    def weight(name: str) -> NDArray:
        return getattr(scorer, name).astype(np.float64)

    out = np.zeros(i.size, dtype=np.float32)
    for e, (a, b) in enumerate(zip(i.tolist(), j.tolist(), strict=True)):
        hidden = weight("edge") @ _edge_features_reference(points, normals, flatness, spacing, a, b)
        hidden += weight("edge_bias")
        for here, there in ((a, b), (b, a)):
            chord = points[there] - points[here]
            cosine = float(normals[here] @ chord) / max(float(np.linalg.norm(chord)), 1e-12)
            facing = []
            for sign in (1.0, -1.0):  # the normal as given, then flipped
                normal = sign * normals[here]
                pooled = np.full(2 * scorer.width, -np.inf)
                for q in nearest[here, : scorer.neighbours].tolist():
                    offset = (points[q] - points[here]) / spacing
                    height = float(offset @ normal)
                    radius = np.sqrt(max(float(offset @ offset) - height**2, 0.0))
                    row = np.array([radius, height, abs(float(normals[q] @ normal))])
                    first = relu(weight("point_1") @ row + weight("point_1_bias"))
                    second = relu(weight("point_2") @ first + weight("point_2_bias"))
                    pooled = np.maximum(pooled, second)
                facing.append(weight("ends") @ pooled)
            if abs(cosine) <= TANGENT_COSINE:
                hidden += 0.5 * (facing[0] + facing[1])
            else:
                hidden += facing[0] if cosine > 0 else facing[1]
        hidden = relu(weight("head_1") @ relu(hidden) + weight("head_1_bias"))
        logit = float((weight("head_2") @ hidden + weight("head_2_bias"))[0])
        out[e] = 1.0 / (1.0 + np.exp(-logit))
    return out


def _edge_features_reference(
    points: NDArray, normals: NDArray, flatness: NDArray, spacing: float, a: int, b: int
) -> NDArray:
    """The six features of :func:`edge_inputs` for one edge ``(a, b)``, in float64."""
    chord = points[b] - points[a]
    length = float(np.linalg.norm(chord))
    unit = chord / max(length, 1e-12)
    cosines = sorted([abs(float(normals[a] @ unit)), abs(float(normals[b] @ unit))])
    flats = sorted([float(flatness[a]), float(flatness[b])])
    agree = abs(float(normals[a] @ normals[b]))
    return np.array([length / spacing, cosines[1], cosines[0], flats[1], flats[0], agree])


def cut_shortcuts(
    graph: sp.csr_array,
    points: NDArray,
    neighbours: tuple[NDArray, NDArray],
    normals: NDArray,
    flatness: NDArray,
    threshold: float,
    scorer: ScorerWeights,
) -> sp.csr_array:
    """``graph`` without the edges ``scorer`` calls shortcuts with a probability above
    ``threshold``, except those it needs to stay joined (:func:`keep_connected`).

    Args:
        graph: ``(N, N)`` CSR of a cloud's edges (chord lengths; any triangle).
        points: ``(N, 3)`` its points; normals, flatness: their
            :func:`~litege_core.learned.cloud_surface.local_surface`.
        neighbours: :func:`~litege_core.engines.graph.knn_neighbours` of ``points`` (itself
            first; searched again here with fewer than ``max(K, 8)`` neighbours). A cloud of
            at most that many points is left as it is.
        threshold: the cut (a probability in ``(0, 1]``; 1 cuts nothing).
    """
    lengths, nearest = neighbours
    reach = max(scorer.neighbours, SPACING_RANK)
    if graph.nnz == 0 or threshold >= 1.0 or points.shape[0] <= reach:
        return graph  # nothing to cut, or a cloud too small to score
    from litege_core.engines.graph import edge_rows, edge_subgraph, knn_neighbours

    if nearest.shape[1] <= reach:
        lengths, nearest = knn_neighbours(points, reach)
    rows = edge_rows(graph)
    scores = shortcut_probabilities(
        scorer,
        points,
        nearest[:, 1:],
        cloud_spacing(lengths),
        normals,
        flatness,
        rows,
        graph.indices.astype(np.int64),
    )
    keep = keep_connected(scores <= threshold, rows, graph.indices, scores, graph.shape[0])
    return edge_subgraph(graph, rows, keep)


def keep_connected(keep: NDArray, i: NDArray, j: NDArray, scores: NDArray, n: int) -> NDArray:
    """``keep`` (``(E,)`` bool over the edges ``(i, j)`` of an ``n``-node graph) plus the cut
    edges that rejoin what the cut split, lowest score first: the cut edges of a minimum
    spanning forest in which kept edges cost nothing and a cut edge its rank by score. The kept
    graph then has the connected components of the whole one: a cut never strands a point or a
    part (whose distances would fall back to the network's)."""
    cut = np.flatnonzero(~keep)
    if cut.size == 0:
        return keep
    from scipy.sparse.csgraph import minimum_spanning_tree

    order = cut[np.argsort(scores[cut], kind="stable")]
    weight = np.full(keep.size, 1e-9)  # kept edges first (a zero would be no edge)
    weight[order] = 1.0 + np.arange(1, order.size + 1) / (order.size + 1)
    forest = minimum_spanning_tree(sp.csr_array((weight, (i, j)), shape=(n, n))).tocoo()
    joins = forest.data > 0.5
    rank = np.rint((forest.data[joins] - 1.0) * (order.size + 1)).astype(np.int64) - 1
    rejoined = keep.copy()
    rejoined[order[rank]] = True
    return rejoined


def save_shortcut_scorer(
    directory: str | os.PathLike,
    state: Mapping[str, Any],
    neighbours: int = NEIGHBOURS,
    training: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write a scorer's ``state`` (the training module's ``state_dict``, stored as float32
    safetensors) and its config into ``directory``; returns the config (``weights_sha256``
    is what a fusion calibration names).

    Raises:
        InputError: weights that are not finite or do not fit together.
    """
    from safetensors.numpy import save_file

    weights = ScorerWeights.from_state(state, neighbours)
    arrays = {key: getattr(weights, name) for name, key in _STATE_KEYS.items()}
    if not all(np.all(np.isfinite(value)) for value in arrays.values()):
        raise InputError("shortcut scorer weights are not finite")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    temporary = directory / (SCORER_WEIGHTS + ".tmp")
    save_file(arrays, str(temporary))
    os.replace(temporary, directory / SCORER_WEIGHTS)
    (directory / SCORER_WEIGHTS).chmod(0o644)  # safetensors writes 0600
    config = {
        "kind": SCORER_KIND,
        "format_version": SCORER_FORMAT,
        "scorer": {"width": weights.width, "neighbours": weights.neighbours},
        "weights_sha256": file_sha256(directory / SCORER_WEIGHTS),
        "training": training or {},
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json_atomic(directory / SCORER_CONFIG, config)
    return config


def load_shortcut_scorer(
    directory: str | os.PathLike | None = None, sha256: str | None = None
) -> ScorerWeights:
    """The scorer in ``directory`` (default: the shipped one, loaded once per process).

    Raises:
        InputError: no scorer there, or its weights are not the ``sha256`` asked for (a fusion
            calibration fitted with another scorer: fit it again).
        ArtifactError: a damaged scorer (bad config, weights that do not match it).
    """
    path = Path(directory).resolve() if directory is not None else SHIPPED_SCORER_DIR
    scorer, found = _load_scorer(str(path))
    if sha256 is not None and found != sha256:
        raise InputError(
            f"the graph fusion was fitted with shortcut scorer {sha256[:12]}…, but "
            f"{path} holds {found[:12]}…; fit the fusion again (scripts/calibrate_fusion.py)"
        )
    return scorer


def shortcut_scorer_sha256(directory: str | os.PathLike | None = None) -> str:
    """The sha256 of the weights of the scorer in ``directory`` (default: the shipped one):
    what a fusion calibration that cuts names."""
    path = Path(directory).resolve() if directory is not None else SHIPPED_SCORER_DIR
    return _load_scorer(str(path))[1]


@functools.lru_cache(maxsize=4)
def _load_scorer(directory: str) -> tuple[ScorerWeights, str]:
    """The scorer of ``directory`` and its weights' sha256 (cached: read-only arrays)."""
    from safetensors.numpy import load_file

    config_path, weights = Path(directory) / SCORER_CONFIG, Path(directory) / SCORER_WEIGHTS
    if not config_path.is_file() or not weights.is_file():
        raise InputError(f"no shortcut scorer in {directory} ({SCORER_CONFIG}, {SCORER_WEIGHTS})")
    config = read_json_object(config_path, f"shortcut scorer {SCORER_CONFIG}")
    if (config.get("kind"), config.get("format_version")) != (SCORER_KIND, SCORER_FORMAT):
        raise ArtifactError(f"{config_path} is not a shortcut scorer of format {SCORER_FORMAT}")
    found = file_sha256(weights)
    if found != config.get("weights_sha256"):
        raise ArtifactError(f"{weights} does not match the sha256 its config records")
    try:
        neighbours = int(config["scorer"]["neighbours"])
        state = load_file(str(weights))
    except (KeyError, TypeError, ValueError, OSError) as exc:
        raise ArtifactError(f"shortcut scorer in {directory} is inconsistent: {exc}") from exc
    scorer = ScorerWeights.from_state(state, neighbours)
    if scorer.width != int(config["scorer"].get("width", -1)):
        raise ArtifactError(f"shortcut scorer in {directory}: its config names another width")
    for name in _STATE_KEYS:
        getattr(scorer, name).flags.writeable = False
    return scorer, found


__all__ = [
    "NEIGHBOURS",
    "SCORER_CONFIG",
    "SCORER_WEIGHTS",
    "SHIPPED_SCORER_DIR",
    "ScorerWeights",
    "cloud_spacing",
    "cut_shortcuts",
    "edge_inputs",
    "keep_connected",
    "load_shortcut_scorer",
    "neighbour_inputs",
    "save_shortcut_scorer",
    "shortcut_probabilities",
    "shortcut_probabilities_reference",
    "shortcut_scorer_sha256",
]
