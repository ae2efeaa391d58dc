"""Pickle-free (de)serialisation of named numpy arrays for the artifact store.

The bytes are a `safetensors <https://github.com/huggingface/safetensors>`_ buffer whose
metadata carries ``format = "litege-artifact-v1"`` plus the caller's string metadata. Loading
never executes code, so bytes read back from a shared cache cannot do more than fail to decode.

What round-trips (checked by the tests with safetensors 0.8): the dtypes ``bool``, ``int8`` …
``int64``, ``uint8`` … ``uint64``, ``float16``, ``float32``, ``float64`` and ``complex64``, with
their exact shape, including 0-d arrays (``shape == ()``) and empty arrays (a zero in the
shape). Big-endian arrays are stored in native (little-endian) order and come back native;
non-contiguous arrays (slices, transposes) are copied to C order first. Object, string,
datetime, void and ``complex128`` arrays are rejected with :class:`ArtifactError`.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping

import numpy as np
from safetensors.numpy import load as _st_load
from safetensors.numpy import save as _st_save

from litege_core.errors import ArtifactError

FORMAT_KEY = "format"
FORMAT_TAG = "litege-artifact-v1"

SUPPORTED_DTYPES: frozenset[np.dtype] = frozenset(
    np.dtype(name)
    for name in (
        "bool",
        "int8",
        "int16",
        "int32",
        "int64",
        "uint8",
        "uint16",
        "uint32",
        "uint64",
        "float16",
        "float32",
        "float64",
        "complex64",
    )
)
"""The numpy dtypes :func:`encode_arrays` accepts (what safetensors stores natively)."""

_HEADER_LEN_BYTES = 8  # safetensors: little-endian u64 header length, then the JSON header


def _prepare(name: str, array: np.ndarray) -> np.ndarray:
    if not isinstance(name, str) or not name or name == "__metadata__":
        raise ArtifactError(f"array name {name!r} must be a non-empty string", name=repr(name))
    array = np.asarray(array)
    if array.dtype.hasobject or array.dtype.kind not in "biufc":
        raise ArtifactError(
            f"array {name!r} has dtype {array.dtype}, which an artifact cannot hold",
            name=name,
            dtype=str(array.dtype),
        )
    native = array.dtype.newbyteorder("=")
    if native not in SUPPORTED_DTYPES:
        raise ArtifactError(
            f"array {name!r} has dtype {array.dtype}; supported: "
            + ", ".join(sorted(str(d) for d in SUPPORTED_DTYPES)),
            name=name,
            dtype=str(array.dtype),
        )
    if array.dtype != native:
        array = array.astype(native)
    # not np.ascontiguousarray: it turns 0-d arrays into 1-d ones
    return array if array.flags.c_contiguous else array.copy(order="C")


def encode_arrays(
    arrays: Mapping[str, np.ndarray], metadata: Mapping[str, str] | None = None
) -> bytes:
    """Serialise named arrays and string metadata to artifact bytes.

    ``metadata`` keys and values must be strings and may not use the reserved key
    ``"format"``. Raises :class:`ArtifactError` for an unsupported dtype, a bad name or bad
    metadata.
    """
    meta: dict[str, str] = {}
    for key, value in (metadata or {}).items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise ArtifactError(
                f"artifact metadata must map str to str, got {key!r}: {type(value).__name__}"
            )
        if key == FORMAT_KEY:
            raise ArtifactError(f"artifact metadata key {FORMAT_KEY!r} is reserved")
        meta[key] = value
    meta[FORMAT_KEY] = FORMAT_TAG
    tensors = {name: _prepare(name, array) for name, array in arrays.items()}
    try:
        return _st_save(tensors, metadata=meta)
    except Exception as exc:  # safetensors raises its own SafetensorError / TypeError
        raise ArtifactError(f"could not encode artifact: {exc}") from exc


def _read_metadata(data: bytes) -> dict[str, str]:
    if len(data) < _HEADER_LEN_BYTES:
        raise ArtifactError(f"artifact is truncated: {len(data)} bytes, no header")
    (header_len,) = struct.unpack("<Q", data[:_HEADER_LEN_BYTES])
    if header_len > len(data) - _HEADER_LEN_BYTES:
        raise ArtifactError(
            f"artifact is truncated: header claims {header_len} bytes, "
            f"{len(data) - _HEADER_LEN_BYTES} follow"
        )
    try:
        header = json.loads(data[_HEADER_LEN_BYTES : _HEADER_LEN_BYTES + header_len])
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ArtifactError(f"artifact header is not valid JSON: {exc}") from exc
    if not isinstance(header, dict):
        raise ArtifactError("artifact header is not a JSON object")
    metadata = header.get("__metadata__") or {}
    if not isinstance(metadata, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in metadata.items()
    ):
        raise ArtifactError("artifact metadata is not a map of strings")
    return metadata


def decode_arrays(data: bytes) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Deserialise artifact bytes to ``(arrays, metadata)``.

    ``metadata`` is what was passed to :func:`encode_arrays` (without the format tag).
    Raises :class:`ArtifactError` -- and nothing else -- for bytes that are corrupt, truncated,
    not a safetensors buffer, or lack the ``litege-artifact-v1`` format tag.
    """
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ArtifactError(f"artifact must be bytes, got {type(data).__name__}")
    data = bytes(data)
    metadata = _read_metadata(data)
    tag = metadata.pop(FORMAT_KEY, None)
    if tag != FORMAT_TAG:
        raise ArtifactError(
            f"artifact format is {tag!r}, expected {FORMAT_TAG!r}", format=repr(tag)
        )
    try:
        arrays = _st_load(data)
    except Exception as exc:  # SafetensorError, or numpy errors for exotic dtypes
        raise ArtifactError(f"artifact is corrupt: {exc}") from exc
    return dict(arrays), metadata


__all__ = ["FORMAT_TAG", "SUPPORTED_DTYPES", "decode_arrays", "encode_arrays"]
