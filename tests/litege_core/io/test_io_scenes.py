"""glTF (``.gltf``) files: embedded buffers, buffer files beside the file, and their bounds."""

import base64
import json
from pathlib import Path

import numpy as np
import pytest

from litege_core.errors import ShapeFileError, ShapeTooLargeError
from litege_core.io import load_shape, save_shape, self_contained_gltf
from litege_core.shape import Shape
from litege_core.synth.folder import folder_digest, list_meshes
from litege_core.validate import ShapeLimits


@pytest.fixture()
def mesh(sphere_mesh):
    vertices, faces = sphere_mesh
    return Shape.from_arrays(vertices.astype(np.float32).astype(np.float64), faces)


@pytest.fixture()
def embedded(tmp_path, mesh) -> Path:
    path = tmp_path / "embedded.gltf"
    save_shape(mesh, path)
    return path


def _with_buffer_files(embedded: Path, folder: Path, uri: str) -> Path:
    """The glTF of ``embedded`` with buffer ``i`` written to the file ``folder / uri`` (``{i}``
    replaced by ``i``, ``%20`` by a space)."""
    document = json.loads(embedded.read_bytes())
    assert len(document["buffers"]) == 2  # trimesh writes positions and faces apart
    for i, buffer in enumerate(document["buffers"]):
        raw = base64.b64decode(buffer["uri"].split(",", 1)[1])
        buffer["uri"] = uri.format(i=i)
        target = folder / buffer["uri"].replace("%20", " ")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(raw)
    path = folder / "external.gltf"
    path.write_text(json.dumps(document))
    return path


def test_the_written_gltf_is_one_self_contained_file(embedded, mesh):
    document = json.loads(embedded.read_bytes())
    assert all(b["uri"].startswith("data:") for b in document["buffers"])
    loaded = load_shape(embedded.read_bytes(), file_format="gltf")  # as an upload
    assert loaded.content_hash == mesh.content_hash


def test_a_buffer_file_beside_the_gltf_is_read_from_its_path(tmp_path, embedded, mesh):
    path = _with_buffer_files(embedded, tmp_path, "data/the%20buffer{i}.bin")
    loaded = load_shape(path)
    assert loaded.content_hash == mesh.content_hash
    assert json.loads(self_contained_gltf(path))["buffers"][0]["uri"].startswith("data:")
    too_few = ShapeLimits(max_vertices=mesh.n_points - 1)
    (tmp_path / "data" / "the buffer0.bin").unlink()  # sizes are checked before any buffer
    with pytest.raises(ShapeTooLargeError, match="vertices"):
        load_shape(path, limits=too_few)


def test_bytes_cannot_name_a_buffer_file(tmp_path, embedded):
    path = _with_buffer_files(embedded, tmp_path, "buffer{i}.bin")
    with pytest.raises(ShapeFileError, match="separate file"):
        load_shape(path.read_bytes(), file_format="gltf")


@pytest.mark.parametrize(
    "uri", ["../outside.bin", "/etc/passwd", "file:///etc/passwd", "http://example.com/b.bin"]
)
def test_a_buffer_file_outside_the_folder_is_refused(tmp_path, embedded, uri):
    folder = tmp_path / "model"
    folder.mkdir()
    document = json.loads(embedded.read_bytes())
    document["buffers"][0]["uri"] = uri
    (tmp_path / "outside.bin").write_bytes(b"\0" * 64)
    path = folder / "model.gltf"
    path.write_text(json.dumps(document))
    with pytest.raises(ShapeFileError, match="folder"):
        load_shape(path)


def test_a_missing_buffer_file_is_a_file_error(tmp_path, embedded):
    path = _with_buffer_files(embedded, tmp_path, "buffer{i}.bin")
    (tmp_path / "buffer1.bin").unlink()
    with pytest.raises(ShapeFileError, match="buffer 1"):
        load_shape(path)


def test_buffer_files_count_against_the_byte_limit(tmp_path, embedded):
    path = _with_buffer_files(embedded, tmp_path, "buffer{i}.bin")
    buffer_bytes = sum((tmp_path / f"buffer{i}.bin").stat().st_size for i in range(2))
    file_bytes = path.stat().st_size
    load_shape(path, limits=ShapeLimits(max_file_bytes=file_bytes + buffer_bytes))
    with pytest.raises(ShapeTooLargeError, match="with its buffers"):
        load_shape(path, limits=ShapeLimits(max_file_bytes=file_bytes + buffer_bytes - 1))


def test_gltf_scene_size_is_checked_before_trimesh(embedded, mesh):
    document = json.loads(embedded.read_bytes())
    document["nodes"] = [{"mesh": 0, "translation": [float(i), 0, 0]} for i in range(3)]
    document["scenes"] = [{"nodes": [0, 1, 2]}]
    data = json.dumps(document).encode()
    assert load_shape(data, file_format="gltf").n_points == 3 * mesh.n_points
    with pytest.raises(ShapeTooLargeError, match="GLTF file has 3 nodes"):
        load_shape(data, file_format="gltf", limits=ShapeLimits(max_scene_nodes=2))
    with pytest.raises(ShapeTooLargeError, match="vertices"):
        load_shape(data, file_format="gltf", limits=ShapeLimits(max_vertices=3 * mesh.n_points - 1))


def test_materials_and_missing_textures_are_not_read(embedded, mesh):
    document = json.loads(embedded.read_bytes())
    document["images"] = [{"uri": "not-here.png"}]
    document["textures"] = [{"source": 0}]
    document["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    document["meshes"][0]["primitives"][0]["material"] = 0
    loaded = load_shape(json.dumps(document).encode(), file_format="gltf")
    assert loaded.content_hash == mesh.content_hash


def test_a_folder_lists_gltf_and_its_digest_covers_the_buffer_file(tmp_path, embedded):
    folder = tmp_path / "collection"
    path = _with_buffer_files(embedded, folder, "buffer{i}.bin")
    assert list_meshes(folder) == (path.name,)
    before = folder_digest(folder, (path.name,))
    raw = bytearray((folder / "buffer1.bin").read_bytes())
    raw[0] ^= 1
    (folder / "buffer1.bin").write_bytes(bytes(raw))
    assert folder_digest(folder, (path.name,)) != before
