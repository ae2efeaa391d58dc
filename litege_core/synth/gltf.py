"""A small glTF 2.0 reader for skinned, animated meshes, and linear blend skinning in numpy.

trimesh loads glTF geometry but does not pose skins, so this module reads the raw document
(``.gltf`` with embedded or external buffers, or binary ``.glb``) itself:

* accessors → numpy arrays (all component types, ``normalized`` integers, byte strides,
  sparse accessors);
* the node hierarchy with each node's rest transform (TRS or ``matrix``);
* the skin of a mesh node: joint nodes and inverse bind matrices; per-vertex ``JOINTS_0/1``
  and ``WEIGHTS_0/1`` (up to 8 influences);
* animations: per-channel samplers (``LINEAR`` with quaternion slerp, ``STEP``, and
  ``CUBICSPLINE`` evaluated as the Hermite spline of the spec).

Posing follows the glTF skinning rule: a vertex ``v`` of a skinned mesh goes to
``Σ_i w_i · G[j_i] · IBM[j_i] · v`` where ``G`` are the joints' global (world) matrices and
``IBM`` the inverse bind matrices; the mesh node's own transform is ignored (spec §3.7.3).
All matrices here are ``(4, 4)`` row-major float64 acting on column vectors.
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ShapeFileError

_COMPONENT: dict[int, type[np.number[Any]]] = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942


@dataclass
class GltfDocument:
    """A parsed glTF document: its JSON and its buffers (bytes)."""

    data: dict
    buffers: list[bytes]

    def accessor(self, index: int) -> NDArray:
        """Accessor ``index`` as ``(count, width)`` (``width`` 1 for scalars, 16 for MAT4 in
        glTF's column-major order); normalized integers are mapped to float64 in [0, 1] /
        [-1, 1]."""
        acc = self.data["accessors"][index]
        dtype = np.dtype(_COMPONENT[acc["componentType"]])
        width = _WIDTH[acc["type"]]
        count = int(acc["count"])
        if "bufferView" in acc:
            array = self._view_elements(
                acc["bufferView"], acc.get("byteOffset", 0), dtype, width, count
            )
        else:
            array = np.zeros((count, width), dtype=dtype)
        if "sparse" in acc:
            array = array.copy()
            sparse = acc["sparse"]
            n = int(sparse["count"])
            idx = sparse["indices"]
            index_type = np.dtype(_COMPONENT[idx["componentType"]])
            rows = self._view_elements(
                idx["bufferView"], idx.get("byteOffset", 0), index_type, 1, n
            )
            val = sparse["values"]
            values = self._view_elements(
                val["bufferView"], val.get("byteOffset", 0), dtype, width, n
            )
            array[rows[:, 0].astype(np.int64)] = values
        if acc.get("normalized", False) and dtype.kind in "iu":
            return np.maximum(array.astype(np.float64) / np.iinfo(dtype).max, -1.0)
        return array

    def _view_elements(
        self, view_index: int, offset: int, dtype, width: int, count: int
    ) -> NDArray:
        view = self.data["bufferViews"][view_index]
        buffer = self.buffers[view["buffer"]]
        start = view.get("byteOffset", 0) + offset
        element = dtype.itemsize * width
        stride = view.get("byteStride", element) or element
        if count == 0:
            return np.zeros((0, width), dtype=dtype)
        end = start + stride * (count - 1) + element
        if end > len(buffer):
            raise ShapeFileError("glTF accessor reads past the end of its buffer")
        raw = np.frombuffer(buffer, dtype=np.uint8, count=end - start, offset=start)
        if stride == element:
            return raw.view(dtype).reshape(count, width)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, element), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)


def read_gltf(path: str | Path) -> GltfDocument:
    """Parse a ``.gltf`` (embedded ``data:`` or external buffers) or ``.glb`` file.

    Raises:
        ShapeFileError: the file is not a readable glTF 2.0 document.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ShapeFileError(f"cannot read {path}: {exc.strerror}") from exc
    binary = None
    if len(raw) >= 12 and struct.unpack_from("<I", raw, 0)[0] == _GLB_MAGIC:
        data, binary = _parse_glb(raw, path)
    else:
        try:
            data = json.loads(raw)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ShapeFileError(f"{path} is neither glTF JSON nor GLB: {exc}") from exc
    buffers = []
    for i, buffer in enumerate(data.get("buffers", [])):
        uri = buffer.get("uri")
        if uri is None:
            if binary is None or i != 0:
                raise ShapeFileError(f"{path}: buffer {i} has no uri and no GLB chunk")
            buffers.append(binary)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            try:
                buffers.append((path.parent / uri).read_bytes())
            except OSError as exc:
                raise ShapeFileError(f"{path}: cannot read buffer {uri}") from exc
    return GltfDocument(data, buffers)


def _parse_glb(raw: bytes, path: Path) -> tuple[dict, bytes | None]:
    offset, data, binary = 12, None, None
    while offset + 8 <= len(raw):
        length, kind = struct.unpack_from("<II", raw, offset)
        chunk = raw[offset + 8 : offset + 8 + length]
        if kind == _CHUNK_JSON:
            data = json.loads(chunk)
        elif kind == _CHUNK_BIN:
            binary = bytes(chunk)
        offset += 8 + length
    if data is None:
        raise ShapeFileError(f"{path}: GLB without a JSON chunk")
    return data, binary


# --------------------------------------------------------------------------- transforms


def quaternion_matrix(q: NDArray) -> NDArray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)`` in glTF order
    ``(x, y, z, w)``."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def trs_matrix(translation: NDArray, rotation: NDArray, scale: NDArray) -> NDArray:
    """``(N, 4, 4)`` matrices ``T · R · S`` of ``(N, 3)`` translations, ``(N, 4)`` quaternions
    (x, y, z, w) and ``(N, 3)`` scales."""
    n = translation.shape[0]
    out = np.zeros((n, 4, 4))
    out[:, :3, :3] = quaternion_matrix(rotation) * scale[:, None, :]
    out[:, :3, 3] = translation
    out[:, 3, 3] = 1.0
    return out


def slerp(a: NDArray, b: NDArray, t: float) -> NDArray:
    """Spherical interpolation of unit quaternions ``(..., 4)`` (shortest arc)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-8
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(small, 1.0, sin))
    wb = np.where(small, t, np.sin(t * theta) / np.where(small, 1.0, sin))
    out = wa * a + wb * b
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


# --------------------------------------------------------------------------- scene model


@dataclass
class Channel:
    """One animation channel: node ``node``'s ``path`` (translation/rotation/scale) sampled at
    ``times (K,)`` seconds with ``values (K, c)`` (``(3K, c)`` for CUBICSPLINE)."""

    node: int
    path: str
    times: NDArray
    values: NDArray
    interpolation: str

    def sample(self, t: float) -> NDArray:
        """The channel's value ``(c,)`` at time ``t`` (clamped to the keyframe range)."""
        times = self.times
        cubic = self.interpolation == "CUBICSPLINE"
        values = self.values.reshape(-1, 3, self.values.shape[-1])[:, 1] if cubic else self.values
        if t <= times[0] or times.size == 1:
            return values[0]
        if t >= times[-1]:
            return values[-1]
        k = int(np.searchsorted(times, t, side="right")) - 1
        dt = float(times[k + 1] - times[k])
        u = (t - times[k]) / dt if dt > 0 else 0.0
        if self.interpolation == "STEP":
            return values[k]
        if cubic:
            triples = self.values.reshape(-1, 3, self.values.shape[-1])
            p0, m0 = triples[k, 1], triples[k, 2] * dt
            p1, m1 = triples[k + 1, 1], triples[k + 1, 0] * dt
            u2, u3 = u * u, u * u * u
            out = (
                (2 * u3 - 3 * u2 + 1) * p0
                + (u3 - 2 * u2 + u) * m0
                + (-2 * u3 + 3 * u2) * p1
                + (u3 - u2) * m1
            )
            return out / np.linalg.norm(out) if self.path == "rotation" else out
        if self.path == "rotation":
            return slerp(values[k], values[k + 1], u)
        return (1.0 - u) * values[k] + u * values[k + 1]


@dataclass
class Clip:
    """An animation: its name, channels and duration (seconds, from 0)."""

    name: str
    channels: list[Channel]

    @property
    def duration(self) -> float:
        return max((float(c.times[-1]) for c in self.channels), default=0.0)


@dataclass
class NodeTree:
    """The node hierarchy: ``parents (N,)`` (-1 for roots), rest ``translation (N, 3)``,
    ``rotation (N, 4)`` (x, y, z, w), ``scale (N, 3)``, and ``matrix`` for nodes given by a
    matrix (NaN rows otherwise: such nodes are not animated by TRS)."""

    names: list[str]
    parents: NDArray
    translation: NDArray
    rotation: NDArray
    scale: NDArray
    matrix: NDArray
    order: NDArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        self.order = _topological_order(self.parents)

    def local_matrices(self, translation=None, rotation=None, scale=None) -> NDArray:
        """``(N, 4, 4)`` local matrices from the given TRS (default: the rest TRS)."""
        t = self.translation if translation is None else translation
        r = self.rotation if rotation is None else rotation
        s = self.scale if scale is None else scale
        local = trs_matrix(t, r, s)
        given = ~np.isnan(self.matrix[:, 0, 0])
        local[given] = self.matrix[given]
        return local

    def global_matrices(self, local: NDArray) -> NDArray:
        """``(N, 4, 4)`` world matrices: each node's local matrix composed with its ancestors'."""
        world = np.empty_like(local)
        for node in self.order:
            parent = self.parents[node]
            world[node] = local[node] if parent < 0 else world[parent] @ local[node]
        return world


def _topological_order(parents: NDArray) -> NDArray:
    order, seen = [], np.zeros(parents.size, dtype=bool)
    for start in range(parents.size):
        chain = []
        node = start
        while node >= 0 and not seen[node]:
            chain.append(node)
            node = int(parents[node])
            if len(chain) > parents.size:
                raise ShapeFileError("glTF node hierarchy has a cycle")
        for n in reversed(chain):
            seen[n] = True
            order.append(n)
    return np.asarray(order, dtype=np.int64)


def node_tree(doc: GltfDocument) -> NodeTree:
    """The document's node hierarchy and rest transforms."""
    nodes = doc.data.get("nodes", [])
    n = len(nodes)
    parents = np.full(n, -1, dtype=np.int64)
    translation, rotation, scale = np.zeros((n, 3)), np.zeros((n, 4)), np.ones((n, 3))
    rotation[:, 3] = 1.0
    matrix = np.full((n, 4, 4), np.nan)
    for i, node in enumerate(nodes):
        for child in node.get("children", []):
            if parents[child] >= 0:
                raise ShapeFileError(f"glTF node {child} has two parents")
            parents[child] = i
        if "matrix" in node:
            matrix[i] = np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
        translation[i] = node.get("translation", translation[i])
        rotation[i] = node.get("rotation", rotation[i])
        scale[i] = node.get("scale", scale[i])
    names = [node.get("name", f"node{i}") for i, node in enumerate(nodes)]
    return NodeTree(names, parents, translation, rotation, scale, matrix)


def clips(doc: GltfDocument) -> list[Clip]:
    """Every animation of the document (TRS channels only; morph weights are ignored)."""
    out = []
    for i, anim in enumerate(doc.data.get("animations", [])):
        channels = []
        for channel in anim["channels"]:
            target = channel["target"]
            if (
                target.get("path") not in ("translation", "rotation", "scale")
                or "node" not in target
            ):
                continue
            sampler = anim["samplers"][channel["sampler"]]
            channels.append(
                Channel(
                    node=int(target["node"]),
                    path=target["path"],
                    times=doc.accessor(sampler["input"])[:, 0].astype(np.float64),
                    values=doc.accessor(sampler["output"]).astype(np.float64),
                    interpolation=sampler.get("interpolation", "LINEAR"),
                )
            )
        out.append(Clip(anim.get("name", f"animation{i}"), channels))
    return out


@dataclass
class SkinnedMesh:
    """A skinned triangle mesh in its bind pose.

    Attributes:
        vertices: ``(V, 3)`` bind-pose positions (as stored; primitives concatenated).
        faces: ``(F, 3)`` int64 triangles.
        joints: ``(V, K)`` int64 indices into ``joint_nodes`` (K = 4 or 8 influences).
        weights: ``(V, K)`` float64 weights, rows summing to 1.
        joint_nodes: ``(J,)`` node index of each skin joint.
        inverse_bind: ``(J, 4, 4)`` inverse bind matrices.
    """

    vertices: NDArray
    faces: NDArray
    joints: NDArray
    weights: NDArray
    joint_nodes: NDArray
    inverse_bind: NDArray


def skinned_mesh(doc: GltfDocument, node: int | None = None) -> SkinnedMesh:
    """The skinned mesh of ``node`` (default: the skinned mesh node with most vertices).

    Raises:
        ShapeFileError: no skinned triangle mesh, or inconsistent attributes.
    """
    nodes = doc.data.get("nodes", [])
    candidates = [i for i, n in enumerate(nodes) if "mesh" in n and "skin" in n]
    if not candidates:
        raise ShapeFileError("the glTF document has no skinned mesh node")
    if node is None:
        node = max(candidates, key=lambda i: _vertex_count(doc, nodes[i]["mesh"]))
    elif node not in candidates:
        raise ShapeFileError(f"glTF node {node} is not a skinned mesh")
    skin = doc.data["skins"][nodes[node]["skin"]]
    joint_nodes = np.asarray(skin["joints"], dtype=np.int64)
    if "inverseBindMatrices" in skin:
        ibm = doc.accessor(skin["inverseBindMatrices"]).astype(np.float64)
        inverse_bind = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)
    else:
        inverse_bind = np.broadcast_to(np.eye(4), (joint_nodes.size, 4, 4)).copy()
    positions, faces, joints, weights, offset = [], [], [], [], 0
    for primitive in doc.data["meshes"][nodes[node]["mesh"]]["primitives"]:
        if primitive.get("mode", 4) != 4:
            continue  # only triangle lists
        attributes = primitive["attributes"]
        if "JOINTS_0" not in attributes or "WEIGHTS_0" not in attributes:
            raise ShapeFileError("a skinned primitive lacks JOINTS_0 / WEIGHTS_0")
        pos = doc.accessor(attributes["POSITION"]).astype(np.float64)
        if "indices" in primitive:
            tri = doc.accessor(primitive["indices"])[:, 0].astype(np.int64).reshape(-1, 3)
        else:
            tri = np.arange(pos.shape[0], dtype=np.int64).reshape(-1, 3)
        j = [doc.accessor(attributes["JOINTS_0"]).astype(np.int64)]
        w = [doc.accessor(attributes["WEIGHTS_0"]).astype(np.float64)]
        if "JOINTS_1" in attributes and "WEIGHTS_1" in attributes:
            j.append(doc.accessor(attributes["JOINTS_1"]).astype(np.int64))
            w.append(doc.accessor(attributes["WEIGHTS_1"]).astype(np.float64))
        positions.append(pos)
        faces.append(tri + offset)
        joints.append(np.concatenate(j, axis=1))
        weights.append(np.concatenate(w, axis=1))
        offset += pos.shape[0]
    if not positions:
        raise ShapeFileError("the skinned mesh has no triangle primitives")
    width = max(j.shape[1] for j in joints)
    joints = [np.pad(j, ((0, 0), (0, width - j.shape[1]))) for j in joints]
    weights = [np.pad(w, ((0, 0), (0, width - w.shape[1]))) for w in weights]
    joint_array, weight_array = np.concatenate(joints), np.concatenate(weights)
    if joint_array.max() >= joint_nodes.size or joint_array.min() < 0:
        raise ShapeFileError("skin joint index out of range")
    total = weight_array.sum(axis=1, keepdims=True)
    if (total <= 0).any():
        raise ShapeFileError("a skinned vertex has no weight")
    return SkinnedMesh(
        vertices=np.concatenate(positions),
        faces=np.concatenate(faces),
        joints=joint_array,
        weights=weight_array / total,
        joint_nodes=joint_nodes,
        inverse_bind=inverse_bind,
    )


def _vertex_count(doc: GltfDocument, mesh: int) -> int:
    return sum(
        int(doc.data["accessors"][p["attributes"]["POSITION"]]["count"])
        for p in doc.data["meshes"][mesh]["primitives"]
    )


def linear_blend_skinning(
    vertices: NDArray, joints: NDArray, weights: NDArray, skin_matrices: NDArray
) -> NDArray:
    """``(V, 3)`` skinned positions ``Σ_k w[v, k] · M[joints[v, k]] · v``.

    Args:
        vertices: ``(V, 3)`` bind-pose positions.
        joints: ``(V, K)`` int joint indices into ``skin_matrices``.
        weights: ``(V, K)`` weights (rows summing to 1).
        skin_matrices: ``(J, 4, 4)`` per-joint matrices (``G · IBM`` for glTF).
    """
    blended = np.einsum("vk,vkij->vij", weights, skin_matrices[joints])  # (V, 4, 4)
    return np.einsum("vij,vj->vi", blended[:, :3, :3], vertices) + blended[:, :3, 3]


def skin_matrices(tree: NodeTree, mesh: SkinnedMesh, local: NDArray) -> NDArray:
    """``(J, 4, 4)`` skinning matrices ``G[joint] · IBM`` for the node ``local`` matrices."""
    world = tree.global_matrices(local)
    return world[mesh.joint_nodes] @ mesh.inverse_bind


def sample_pose(tree: NodeTree, clip: Clip, t: float) -> tuple[NDArray, NDArray, NDArray]:
    """Node TRS ``(N, 3), (N, 4), (N, 3)`` at time ``t`` of ``clip`` (rest TRS where the clip
    has no channel)."""
    translation, rotation, scale = tree.translation.copy(), tree.rotation.copy(), tree.scale.copy()
    targets = {"translation": translation, "rotation": rotation, "scale": scale}
    for channel in clip.channels:
        targets[channel.path][channel.node] = channel.sample(t)
    return translation, rotation, scale


__all__ = [
    "Channel",
    "Clip",
    "GltfDocument",
    "NodeTree",
    "SkinnedMesh",
    "clips",
    "linear_blend_skinning",
    "node_tree",
    "quaternion_matrix",
    "read_gltf",
    "sample_pose",
    "skin_matrices",
    "skinned_mesh",
    "slerp",
    "trs_matrix",
]
