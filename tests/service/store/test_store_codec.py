"""The artifact codec (safetensors, pickle-free) and the key scheme."""

from __future__ import annotations

import contextlib
import json
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from safetensors.numpy import save as st_save

from litege_core.errors import ArtifactError, InputError
from service.store import FORMAT_TAG, artifact_key, decode_arrays, encode_arrays, geometry_key
from service.store.codec import SUPPORTED_DTYPES

DTYPES = ["float64", "float32", "int64", "uint8", "bool", "int32", "float16", "complex64"]
SHAPES = [(), (0,), (0, 3), (3, 0, 2), (7,), (5, 3), (2, 3, 4)]


def _example(dtype: str, shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = rng.normal(size=shape) * 100
    if dtype == "bool":
        return values > 0
    if dtype == "complex64":
        return (values + 1j * values[::-1] if values.ndim else values + 2j).astype(dtype)
    return values.astype(dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_round_trip_preserves_dtype_shape_and_values(dtype: str, shape: tuple[int, ...]) -> None:
    array = _example(dtype, shape)
    arrays, metadata = decode_arrays(encode_arrays({"x": array}))
    assert set(arrays) == {"x"}
    assert arrays["x"].dtype == np.dtype(dtype)
    assert arrays["x"].shape == shape
    np.testing.assert_array_equal(arrays["x"], array)
    assert metadata == {}


def test_several_arrays_and_metadata_round_trip() -> None:
    vertices = np.random.default_rng(1).normal(size=(10, 3))
    faces = np.array([[0, 1, 2], [2, 3, 4]], dtype=np.int64)
    meta = {"shape_id": "abc", "n_vertices": "10", "unicode": "géodésique"}
    data = encode_arrays({"vertices": vertices, "faces": faces, "flag": np.array(True)}, meta)
    assert isinstance(data, bytes)
    arrays, metadata = decode_arrays(data)
    assert metadata == meta
    np.testing.assert_array_equal(arrays["vertices"], vertices)
    np.testing.assert_array_equal(arrays["faces"], faces)
    assert arrays["flag"].shape == () and arrays["flag"].dtype == np.bool_ and arrays["flag"]


def test_no_arrays_is_a_valid_artifact() -> None:
    assert decode_arrays(encode_arrays({}, {"k": "v"})) == ({}, {"k": "v"})


def test_format_tag_is_in_the_safetensors_header() -> None:
    data = encode_arrays({"x": np.zeros(2)})
    (n,) = struct.unpack("<Q", data[:8])
    assert json.loads(data[8 : 8 + n])["__metadata__"] == {"format": FORMAT_TAG}


@pytest.mark.parametrize(
    "array",
    [
        np.arange(24.0).reshape(4, 6)[:, ::2],  # strided
        np.asfortranarray(np.arange(12, dtype=np.int64).reshape(3, 4)),
        np.arange(12.0).reshape(3, 4).T,
        np.arange(5, dtype=">f8"),  # big-endian
        np.arange(5, dtype=">i4")[::-1],
    ],
    ids=["strided", "fortran", "transposed", "big-endian", "big-endian-reversed"],
)
def test_non_contiguous_and_non_native_arrays_are_stored_as_native_c_order(
    array: np.ndarray,
) -> None:
    arrays, _ = decode_arrays(encode_arrays({"a": array}))
    np.testing.assert_array_equal(arrays["a"], array)
    assert arrays["a"].dtype == array.dtype.newbyteorder("=")
    assert arrays["a"].flags.c_contiguous


@pytest.mark.parametrize(
    "array",
    [
        np.array([{"a": 1}, None], dtype=object),
        np.array(["ab", "c"]),
        np.array([b"ab"]),
        np.array(["2020-01-01"], dtype="datetime64[D]"),
        np.zeros(2, dtype=np.complex128),
        np.zeros(2, dtype=[("a", "f8"), ("b", "i4")]),
    ],
    ids=["object", "unicode", "bytes", "datetime", "complex128", "structured"],
)
def test_unsupported_dtypes_are_rejected(array: np.ndarray) -> None:
    with pytest.raises(ArtifactError, match="dtype"):
        encode_arrays({"a": array})


def test_supported_dtypes_are_what_the_docs_say() -> None:
    assert {str(d) for d in SUPPORTED_DTYPES} >= {"float64", "float32", "int64", "uint8", "bool"}
    assert np.dtype(object) not in SUPPORTED_DTYPES


@pytest.mark.parametrize(
    "metadata",
    [{"format": "mine"}, {"n": 3}, {1: "x"}],
    ids=["reserved-key", "int-value", "int-key"],
)
def test_bad_metadata_is_rejected(metadata: dict) -> None:
    with pytest.raises(ArtifactError):
        encode_arrays({"a": np.zeros(1)}, metadata)


@pytest.mark.parametrize("name", ["", "__metadata__", 3])
def test_bad_array_names_are_rejected(name: object) -> None:
    with pytest.raises(ArtifactError, match="name"):
        encode_arrays({name: np.zeros(1)})  # type: ignore[dict-item]


def test_every_truncation_raises_artifact_error() -> None:
    data = encode_arrays({"v": np.arange(6.0).reshape(2, 3), "f": np.arange(3)}, {"k": "v"})
    for cut in range(len(data)):
        with pytest.raises(ArtifactError):
            decode_arrays(data[:cut])


@pytest.mark.parametrize(
    "data",
    [b"", b"\x00", b"not an artifact at all", bytes(64), b"\xff" * 64, b"\x05" + bytes(7)],
)
def test_garbage_raises_artifact_error(data: bytes) -> None:
    with pytest.raises(ArtifactError):
        decode_arrays(data)


def test_a_safetensors_buffer_without_our_tag_is_rejected() -> None:
    with pytest.raises(ArtifactError, match="format"):
        decode_arrays(st_save({"a": np.zeros(2)}))
    with pytest.raises(ArtifactError, match="format"):
        decode_arrays(st_save({"a": np.zeros(2)}, metadata={"format": "pt"}))


def test_header_lying_about_the_data_raises_artifact_error() -> None:
    data = encode_arrays({"a": np.zeros(4)})
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8 : 8 + n])
    header["a"]["data_offsets"] = [0, 64]  # more than the buffer holds
    forged = json.dumps(header).encode()
    with pytest.raises(ArtifactError):
        decode_arrays(struct.pack("<Q", len(forged)) + forged + data[8 + n :])


def test_non_bytes_input_raises_artifact_error_and_bytes_likes_are_accepted() -> None:
    with pytest.raises(ArtifactError):
        decode_arrays("text")  # type: ignore[arg-type]
    data = encode_arrays({"a": np.arange(3)})
    for view in (bytearray(data), memoryview(data)):
        np.testing.assert_array_equal(decode_arrays(view)[0]["a"], np.arange(3))


_VALID = encode_arrays({"v": np.arange(6.0).reshape(2, 3), "m": np.eye(2, dtype=bool)}, {"k": "v"})


@settings(max_examples=200, deadline=None)
@given(position=st.integers(0, len(_VALID) - 1), byte=st.integers(0, 255))
def test_a_flipped_byte_decodes_or_raises_artifact_error(position: int, byte: int) -> None:
    corrupted = bytearray(_VALID)
    corrupted[position] = byte
    with contextlib.suppress(ArtifactError):  # anything else fails the test
        decode_arrays(bytes(corrupted))


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=200))
def test_arbitrary_bytes_decode_or_raise_artifact_error(data: bytes) -> None:
    with contextlib.suppress(ArtifactError):  # anything else fails the test
        decode_arrays(data)


# -- keys --------------------------------------------------------------------------------------


def test_key_layout_geometry_once_per_shape_artifacts_per_bundle_beside_it() -> None:
    assert geometry_key("shape-7") == "litege:{shape-7}:geometry"
    assert artifact_key("shape-7", "b1a2", "record") == "litege:{shape-7}:b1a2:record"
    # the Redis Cluster hash tag (the part in braces) is the shape id for all of them
    for key in (geometry_key("s"), artifact_key("s", "b", "record"), artifact_key("s", "m", "x")):
        assert key[key.index("{") + 1 : key.index("}")] == "s"


@pytest.mark.parametrize(
    "parts",
    [
        ("", "s", "a"),
        ("b", "", "a"),
        ("b", "s", ""),
        ("b:x", "s", "a"),
        ("b", "s:1", "a"),
        ("b", "s", "a:b"),
        ("b", "s 1", "a"),
        ("b", "s", "a\tb"),
        ("b\n", "s", "a"),
        ("b", "s\u00a0", "a"),  # unicode whitespace
        ("b", 7, "a"),
        (None, "s", "a"),
        ("s{x}", "b", "a"),  # braces would move the hash tag
        ("s", "b}", "a"),
        ("s", "b", "{a"),
    ],
)
def test_artifact_key_rejects_bad_parts(parts: tuple) -> None:
    with pytest.raises(InputError):
        artifact_key(*parts)


@pytest.mark.parametrize("shape_id", ["", "a:b", "a b", "{a}", "a}", None, 7])
def test_geometry_key_rejects_bad_shape_ids(shape_id: object) -> None:
    with pytest.raises(InputError):
        geometry_key(shape_id)  # type: ignore[arg-type]
