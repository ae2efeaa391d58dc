"""Python stubs of ``proto/litege.proto``: generated on demand, never committed.

``python -m service.grpc_stubs`` (or the first :func:`load_stubs` in a process whose stubs are
missing or stale) runs ``grpc_tools.protoc`` and writes into ``service/_generated/``::

    __init__.py
    litege_pb2.py, litege_pb2.pyi      messages
    litege_pb2_grpc.py                 service stub / servicer (imports ``.litege_pb2``)
    PROTO_SHA256                       hex SHA-256 of the .proto the stubs were made from

The stubs are *stale* when ``PROTO_SHA256`` differs from the current .proto's hash. Generation is
safe to run from several processes at once: each one writes a private temporary directory and
moves the files into place with atomic renames, ``PROTO_SHA256`` last, so a reader sees either
the old or the new complete file. A read-only install with stale stubs raises
:class:`~litege_core.errors.MissingDependencyError` (generate them at build time instead).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import os
import re
import shutil
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

from litege_core.errors import ArtifactError, MissingDependencyError

PROTO_PATH = Path(__file__).resolve().parents[1] / "proto" / "litege.proto"
GENERATED_DIR = Path(__file__).resolve().parent / "_generated"
GENERATED_PACKAGE = f"{__package__ or 'service'}._generated"
HASH_FILE = "PROTO_SHA256"
STUB_FILES = ("__init__.py", "litege_pb2.py", "litege_pb2.pyi", "litege_pb2_grpc.py")
REGENERATE_HINT = "run `python -m service.grpc_stubs` where the package directory is writable"

_lock = threading.Lock()
_INIT_TEXT = '"""Generated from proto/litege.proto by service.grpc_stubs; do not edit."""\n'


def proto_sha256(proto: Path = PROTO_PATH) -> str:
    """Hex SHA-256 of the .proto file's bytes."""
    return hashlib.sha256(proto.read_bytes()).hexdigest()


def recorded_sha256(out_dir: Path = GENERATED_DIR) -> str | None:
    """The hash recorded with the generated stubs, ``None`` when any stub file is missing."""
    try:
        recorded = (out_dir / HASH_FILE).read_text().strip()
    except OSError:
        return None
    if not all((out_dir / name).is_file() for name in STUB_FILES):
        return None
    return recorded or None


def is_stale(proto: Path = PROTO_PATH, out_dir: Path = GENERATED_DIR) -> bool:
    """Whether the stubs are missing or were generated from another version of the .proto."""
    return recorded_sha256(out_dir) != proto_sha256(proto)


def _writable(out_dir: Path) -> bool:
    probe = out_dir if out_dir.exists() else out_dir.parent
    return os.access(probe, os.W_OK | os.X_OK)


def generate(proto: Path = PROTO_PATH, out_dir: Path = GENERATED_DIR) -> Path:
    """Run protoc on ``proto`` and move the stubs into ``out_dir`` atomically.

    Raises:
        MissingDependencyError: grpcio-tools is missing, or ``out_dir`` is not writable.
        ArtifactError: protoc rejected the .proto.
    """
    try:
        from grpc_tools import protoc
    except ImportError as exc:
        raise MissingDependencyError(
            "generating the gRPC stubs needs grpcio-tools (pip install 'litege[service]'); "
            f"or {REGENERATE_HINT} at build time",
            dependency="grpcio-tools",
        ) from exc
    source = proto.read_bytes()  # hash exactly the bytes protoc compiles
    digest = hashlib.sha256(source).hexdigest()
    if not _writable(out_dir):
        raise MissingDependencyError(
            f"the gRPC stubs in {out_dir} are missing or stale and the directory is not "
            f"writable; {REGENERATE_HINT}"
        )
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=out_dir, prefix=".tmp-") as tmp:
            src_dir, build_dir = Path(tmp, "src"), Path(tmp, "build")
            src_dir.mkdir()
            build_dir.mkdir()
            (src_dir / proto.name).write_bytes(source)
            well_known = Path(protoc.__file__).parent / "_proto"
            args = [
                "grpc_tools.protoc",
                f"-I{src_dir}",
                f"-I{well_known}",
                f"--python_out={build_dir}",
                f"--pyi_out={build_dir}",
                f"--grpc_python_out={build_dir}",
                proto.name,
            ]
            if protoc.main(args) != 0:
                raise ArtifactError(f"protoc failed on {proto} (see its messages above)")
            grpc_module = build_dir / "litege_pb2_grpc.py"
            text, count = re.subn(
                r"^import litege_pb2 as ",
                "from . import litege_pb2 as ",
                grpc_module.read_text(),
                flags=re.MULTILINE,
            )
            if count != 1:
                raise ArtifactError("unexpected import layout in protoc's litege_pb2_grpc.py")
            grpc_module.write_text(text)
            (build_dir / "__init__.py").write_text(_INIT_TEXT)
            (build_dir / HASH_FILE).write_text(digest + "\n")
            for name in (*STUB_FILES, HASH_FILE):  # the hash last: it marks completion
                os.replace(build_dir / name, out_dir / name)
    except OSError as exc:
        raise MissingDependencyError(
            f"cannot write the gRPC stubs to {out_dir} ({exc}); {REGENERATE_HINT}"
        ) from exc
    return out_dir


def _import_stubs() -> tuple[ModuleType, ModuleType]:
    importlib.invalidate_caches()
    pb2 = importlib.import_module(f"{GENERATED_PACKAGE}.litege_pb2")
    pb2_grpc = importlib.import_module(f"{GENERATED_PACKAGE}.litege_pb2_grpc")
    return pb2, pb2_grpc


def _forget_stubs() -> None:
    for name in [m for m in sys.modules if m.startswith(GENERATED_PACKAGE)]:
        del sys.modules[name]


def load_stubs() -> tuple[ModuleType, ModuleType]:
    """``(litege_pb2, litege_pb2_grpc)``, generating them first when missing or stale.

    Once imported, the modules stay for the life of the process.

    Raises:
        MissingDependencyError: the stubs are missing or stale and cannot be (re)generated, or
            they do not import with the installed protobuf / grpcio.
    """
    with _lock:
        loaded = f"{GENERATED_PACKAGE}.litege_pb2_grpc" in sys.modules
        if not loaded and PROTO_PATH.is_file() and is_stale():
            generate()
        elif not loaded and recorded_sha256() is None:
            raise MissingDependencyError(
                f"the gRPC stubs are missing and {PROTO_PATH} is not available; {REGENERATE_HINT}"
            )
        try:
            return _import_stubs()
        except Exception as first:  # e.g. protobuf's VersionError: made by another protoc
            _forget_stubs()
            if not (PROTO_PATH.is_file() and _writable(GENERATED_DIR)):
                raise MissingDependencyError(
                    f"the generated gRPC stubs do not import ({first}); {REGENERATE_HINT}"
                ) from first
            generate()
            try:
                return _import_stubs()
            except Exception as second:
                _forget_stubs()
                raise MissingDependencyError(
                    f"the generated gRPC stubs do not import ({second}); check that grpcio, "
                    "grpcio-tools and protobuf versions match"
                ) from second


def main(argv: list[str] | None = None) -> int:
    """``python -m service.grpc_stubs [--check]``."""
    parser = argparse.ArgumentParser(prog="python -m service.grpc_stubs", description=__doc__)
    parser.add_argument(
        "--check", action="store_true", help="only report; exit 1 when the stubs are stale"
    )
    parser.add_argument("--clean", action="store_true", help="delete the stubs first")
    args = parser.parse_args(argv)
    if args.check:
        stale = is_stale()
        print(f"{GENERATED_DIR}: {'stale or missing' if stale else 'up to date'}")
        return 1 if stale else 0
    if args.clean and GENERATED_DIR.exists():
        shutil.rmtree(GENERATED_DIR)
    try:
        out = generate()
    except (MissingDependencyError, ArtifactError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"generated gRPC stubs from {PROTO_PATH} in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
