"""Helpers shared by the ``litege`` sub-commands: argument groups, index lists, the model a
command runs, and output files. Heavy imports (torch, the model) happen inside functions."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from litege_core.errors import InputError

if TYPE_CHECKING:
    from litege_core.learned import NumpyPredictor, Predictor

SHAPE_KINDS = ("mesh", "point_cloud")
SHAPE_FILE_HELP = "mesh or point-cloud file (OBJ, PLY, OFF, STL, GLB, glTF, XYZ, NPY)"


def parse_indices(text: str, what: str) -> list[int]:
    """``"0,17,42"`` → ``[0, 17, 42]``; anything else is an :class:`InputError` naming
    the ``--what`` flag."""
    items = [item.strip() for item in text.split(",")]
    try:
        return [int(item) for item in items]
    except ValueError:
        raise InputError(
            f"--{what} must be comma-separated integer indices, got {text!r}"
        ) from None


def split_list(text: str | None, allowed: Sequence[str], what: str) -> list[str]:
    """``"a,b"`` → ``["a", "b"]`` checked against ``allowed`` (``""`` → none)."""
    items = [item.strip() for item in (text or "").split(",") if item.strip()]
    unknown = [item for item in items if item not in allowed]
    if unknown:
        raise InputError(f"--{what}: unknown {unknown}; expected a subset of {list(allowed)}")
    return items


def predictor(args: argparse.Namespace) -> Predictor:
    """The geodesic :class:`~litege_core.learned.Predictor` of ``--model``/``--bundle`` on
    ``--device`` (see :func:`add_bundle_arguments`), with ``--head`` where the command has
    it (:func:`add_head_argument`) and ``--fusion`` (:func:`add_fusion_argument`)."""
    from pathlib import Path

    from litege_core.device import resolve_device
    from litege_core.learned import DEFAULT_MODEL, Predictor, load_bundle, load_shipped

    device = resolve_device(args.device)
    if args.bundle is not None:
        bundle = load_bundle(args.bundle, device)
    elif args.model is not None and Path(args.model).is_dir():  # --model takes a path too
        bundle = load_bundle(args.model, device)
    else:
        bundle = load_shipped(args.model or DEFAULT_MODEL, device)
    return Predictor(
        bundle,
        device,
        head=getattr(args, "head", "auto"),
        descriptor_lattice=getattr(args, "lattice", "auto"),
        fusion=getattr(args, "fusion", "auto"),
    )


def with_model(args: argparse.Namespace, model: str) -> argparse.Namespace:
    """``args`` with ``--model`` set to ``model`` (one command, several models)."""
    return argparse.Namespace(**{**vars(args), "model": model})


def numpy_predictor(args: argparse.Namespace) -> NumpyPredictor:
    """The torch-free runtime of ``--model``/``--bundle`` (see :func:`predictor`)."""
    from pathlib import Path

    from litege_core.learned.manifest import DEFAULT_MODEL
    from litege_core.learned.numpy_predictor import NumpyPredictor

    options = {
        "head": getattr(args, "head", "auto"),
        "lattice": getattr(args, "lattice", "auto"),
        "fusion": getattr(args, "fusion", "auto"),
    }
    if args.bundle is not None:
        return NumpyPredictor(args.bundle, **options)
    if args.model is not None and Path(args.model).is_dir():
        return NumpyPredictor(args.model, **options)
    return NumpyPredictor.shipped(args.model or DEFAULT_MODEL, **options)


def save_npy(path: str, array: Any) -> None:
    """Write ``array`` to exactly ``path`` (``np.save`` would append ``.npy``)."""
    import numpy as np

    try:
        with open(path, "wb") as handle:
            np.save(handle, array)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror}") from exc


def write_json(path: str, data: Any) -> None:
    """Write ``data`` as indented JSON to ``path``; failures are :class:`InputError`."""
    try:
        with open(path, "w", encoding="utf-8") as handle:
            json.dump(data, handle, indent=2)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror}") from exc


def print_json(data: Any) -> None:
    """A command's summary on stdout."""
    print(json.dumps(data, indent=2))


def add_device_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto")


def add_precision_argument(parser: argparse.ArgumentParser, default: str = "auto") -> None:
    """``--precision`` of a matching search's head (checked where the model is built)."""
    parser.add_argument(
        "--precision",
        default=default,
        help="arithmetic of the search's head: float32, bfloat16, int8 or auto "
        "(bfloat16 where the CPU or GPU runs it fast)",
    )


def add_kind_argument(parser: argparse.ArgumentParser, flag: str = "--kind") -> None:
    parser.add_argument(flag, choices=SHAPE_KINDS, default=None)


def add_bundle_arguments(parser: argparse.ArgumentParser) -> None:
    """``--model NAME`` or ``--bundle DIR`` of a geodesic model, and ``--device``."""
    which = parser.add_mutually_exclusive_group()
    which.add_argument(
        "--model", default=None, help="shipped model name or bundle directory (default: quadrupeds)"
    )
    which.add_argument("--bundle", default=None, help="model bundle directory")
    add_device_argument(parser)


LATTICE_CHOICES = ("auto", "full", "bcc", "stride2")
"""The descriptor lattices (:data:`litege_core.descriptor.basis.LATTICE_CHOICES`, listed here so
that building the parser imports no descriptor code; a test keeps the two equal)."""


HEAD_CHOICES = ("auto", "full", "small")
"""The distance heads (:data:`litege_core.learned.manifest.HEAD_CHOICES`, listed here for the
same reason as :data:`LATTICE_CHOICES`; a test keeps the two equal)."""


def add_head_argument(parser: argparse.ArgumentParser) -> None:
    """``--head auto|full|small`` (the trained distance head or the bundle's distilled one)
    and ``--lattice auto|full|bcc|stride2`` (the voxels whose UDF the descriptor samples): the
    speed options of the learned engine."""
    parser.add_argument(
        "--head",
        choices=HEAD_CHOICES,
        default="auto",
        help="distance head: auto (default: the model's distilled small head when it ships "
        "one, as the shipped ones do, else full), full (the trained head: ~18x more "
        "operations per pair, slightly more accurate) or small",
    )
    parser.add_argument(
        "--lattice",
        choices=LATTICE_CHOICES,
        default="auto",
        help="descriptor voxels: auto (default: stride2 where the model's basis allows it, "
        "as the shipped ones do, else full), full (every voxel), bcc (1/4) or stride2 (1/8)",
    )


FUSIONS = ("auto", "none", "graph")
"""The learned engine's fusions (:data:`litege_core.learned.fusion.FUSIONS`, listed here for the
same reason as :data:`LATTICE_CHOICES`; a test keeps the two equal)."""
ROUTES = ("auto", "learned", "surface")
"""Learned paths' routes (:data:`litege_core.learned.paths.ROUTES`, listed here for the same
reason; a test keeps the two equal)."""


def add_fusion_argument(parser: argparse.ArgumentParser) -> None:
    """``--fusion auto|none|graph``: the model's calibrated graph Dijkstra (a mesh's edges
    alone, a cloud's network-pruned kNN graph blended with the network;
    :mod:`litege_core.learned.fusion`) where the model ships a calibration, or the network
    alone."""
    parser.add_argument(
        "--fusion",
        choices=FUSIONS,
        default="auto",
        help="auto (default: graph where the model ships a fusion calibration, as the shipped "
        "ones do, else none), none (the network's distances: fastest on clouds) or graph (a "
        "calibrated graph Dijkstra: a mesh's own edges alone, a cloud's kNN graph blended with "
        "the network, weighted by how unusual the shape is and how dense its points are: more "
        "accurate on real shapes; refused for a model without a calibration)",
    )


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """A shape file, its kind, the geodesic model, the descriptor seed and ``-o FILE.npy``."""
    parser.add_argument("file", help=SHAPE_FILE_HELP)
    add_kind_argument(parser)
    add_bundle_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the descriptor samples")
    parser.add_argument("-o", "--output", required=True, help="output .npy file")


__all__ = [
    "FUSIONS",
    "HEAD_CHOICES",
    "LATTICE_CHOICES",
    "ROUTES",
    "SHAPE_FILE_HELP",
    "SHAPE_KINDS",
    "add_bundle_arguments",
    "add_device_argument",
    "add_fusion_argument",
    "add_head_argument",
    "add_kind_argument",
    "add_model_arguments",
    "numpy_predictor",
    "parse_indices",
    "predictor",
    "print_json",
    "save_npy",
    "split_list",
    "with_model",
    "write_json",
]
