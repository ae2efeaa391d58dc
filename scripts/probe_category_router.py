"""Probe: can a category classifier fitted on generated shapes route real shapes better than the
lowest OOD z-score (issue 14, `auto` routing)?

Usage: python scripts/probe_category_router.py [--eval-data ../shared/eval-data]

Training shapes (no dev shape): 80 procedural quadrupeds and 80 procedural bipeds (held-out
seeds), 36 posed rigged animals and 60 posed MakeHuman bodies (``../shared/train-data``) and the
24 static animals of ``data/folder-cal`` (``scripts/build_folder_cal.py``; skipped when absent),
each sampled three times at 300–5,000 surface points, a third of them with noise. Features of a
point set, all invariant to rotation and to the PCA axis signs: PCA eigenvalue ratios, per-axis
skewness magnitude and kurtosis, histograms of pair distances (D2), of radii, of |coordinate|
per PCA axis and of triangle angles (A3), plus both shipped models' OOD z-scores. A logistic
regression (L2) on them; reported: its leave-one-group-out error on the generated groups, and
how it routes the TOSCA animals and FAUST humans (2,000 and 300 surface points, and 2,000 with
noise 0.01) next to the shipped rule (lowest z-score). Prints a markdown section. An
exploration, not a shipped component.
"""

from __future__ import annotations

import argparse
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core import synth
from litege_core.datasets.factories import RiggedFactory
from litege_core.evaluation.geodesic import collection_eval_shapes, real_shape_paths, unit_area
from litege_core.io import load_shape
from litege_core.learned import Predictor, load_shipped
from litege_core.sampling import sample_surface
from litege_core.shape import Shape
from litege_core.synth.makehuman import cached_makehuman, posed_human
from litege_core.synth.rigged import ANIMALS

Mesh = tuple[str, NDArray, NDArray]


def generated_meshes(train_data: str) -> list[tuple[Mesh, bool]]:
    """``((group, vertices, faces), is_quadruped)`` of every training shape."""
    out: list[tuple[Mesh, bool]] = []
    for category in ("quadruped", "biped"):
        names, faces = synth.families(category), np.asarray(synth.template(category).faces)
        for k in range(80):
            shape = synth.generate_shape(category, names[k % len(names)], 4_000_000 + k)
            mesh = (f"procedural {category}s", shape.vertices, faces)
            out.append((mesh, category == "quadruped"))
    rigged = RiggedFactory(train_data)
    for k in range(36):
        vertices, faces = rigged.generate_mesh(ANIMALS[k % len(ANIMALS)], 4_000_000 + k)
        out.append((("rigged animals", vertices, faces), True))
    humans = cached_makehuman(str(Path(train_data) / "makehuman"))
    for k in range(60):
        vertices, faces, _ = posed_human(humans, 4_000_000 + k)
        out.append((("MakeHuman bodies", vertices, faces), False))
    if Path("data/folder-cal").is_dir():
        for static in collection_eval_shapes("data/folder-cal"):
            out.append((("static animals (folder-cal)", static.vertices, static.faces), True))
    return out


def surface_points(mesh: Mesh, n: int, noise: float, rng: np.random.Generator) -> NDArray:
    """``n`` area-weighted samples of the unit-area mesh, with Gaussian noise ``noise``."""
    _, vertices, faces = mesh
    unit, _ = unit_area(np.asarray(vertices, np.float64), np.asarray(faces))
    points = sample_surface(unit, np.asarray(faces), n, rng).points
    return points + rng.normal(size=points.shape) * noise


def geometric_features(points: NDArray, rng: np.random.Generator) -> NDArray:
    """Rotation- and sign-invariant global features of a ``(P, 3)`` point set."""
    centred = points - points.mean(axis=0)
    scaled = centred / np.sqrt((centred**2).sum(axis=1).mean())
    values, vectors = np.linalg.eigh(np.cov(scaled.T))
    values, vectors = values[::-1], vectors[:, ::-1]
    coords = scaled @ vectors
    spread = coords.std(axis=0)
    features = [values[1] / values[0], values[2] / values[0]]
    features += list(np.abs((coords**3).mean(axis=0)) / spread**3)
    features += list((coords**4).mean(axis=0) / spread**4)
    i, j = rng.integers(0, len(scaled), (2, 3000))
    pairs = np.linalg.norm(scaled[i] - scaled[j], axis=1)
    features += list(np.histogram(pairs, 24, (0, 3.6))[0] / pairs.size)
    radii = np.linalg.norm(scaled, axis=1)
    features += list(np.histogram(radii, 16, (0, 2.6))[0] / radii.size)
    for axis in range(3):
        along = np.abs(coords[:, axis]) / spread[axis]
        features += list(np.histogram(along, 8, (0, 3.2))[0] / along.size)
    a, b, c = rng.integers(0, len(scaled), (3, 2000))
    u, w = scaled[a] - scaled[b], scaled[c] - scaled[b]
    norms = np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1) + 1e-9
    features += list(np.histogram((u * w).sum(axis=1) / norms, 12, (-1, 1))[0] / len(a))
    return np.asarray(features)


class Scorer:
    """Both shipped geodesic models' OOD z-scores of a point set."""

    def __init__(self) -> None:
        self.models = [
            Predictor(load_shipped(name), fusion="none") for name in ("quadrupeds", "humans")
        ]

    def __call__(self, points: NDArray) -> NDArray:
        shape = Shape.from_arrays(points)
        z = [model.register(shape).ood_score for model in self.models]
        return np.array([z[0], z[1], z[0] - z[1]])


def fit_logistic(x: NDArray, y: NDArray, lam: float) -> tuple[NDArray, NDArray, NDArray, float]:
    """Standardisation and L2 logistic regression by Newton steps."""
    mean, std = x.mean(axis=0), x.std(axis=0) + 1e-6
    z = np.c_[(x - mean) / std, np.ones(len(x))]
    weights = np.zeros(z.shape[1])
    penalty = lam * np.diag(np.r_[np.ones(z.shape[1] - 1), 0.0])
    for _ in range(60):
        p = 1.0 / (1.0 + np.exp(-(z @ weights)))
        gradient = z.T @ (p - y) / len(y) + penalty @ weights
        hessian = (z.T * (p * (1 - p))) @ z / len(y) + penalty + 1e-9 * np.eye(len(weights))
        weights -= np.linalg.solve(hessian, gradient)
    return mean, std, weights[:-1], float(weights[-1])


def probability(model: tuple[NDArray, NDArray, NDArray, float], x: NDArray) -> NDArray:
    mean, std, weights, bias = model
    return 1.0 / (1.0 + np.exp(-(((x - mean) / std) @ weights + bias)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--train-data", default="../shared/train-data")
    parser.add_argument("--lam", type=float, default=0.01)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    scorer = Scorer()
    rows, labels, groups = [], [], []
    for mesh, quadruped in generated_meshes(args.train_data):
        for _ in range(3):
            n = int(np.exp(rng.uniform(np.log(300), np.log(5000))))
            points = surface_points(mesh, n, float(rng.choice([0, 0, 0.005, 0.01])), rng)
            rows.append(np.r_[geometric_features(points, rng), scorer(points)])
            labels.append(quadruped)
            groups.append(mesh[0])
    x, y, group = np.asarray(rows), np.asarray(labels, float), np.asarray(groups)
    model = fit_logistic(x, y, args.lam)
    print("### A category classifier for `auto` routing: probe (issue 14)\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; {len(x)} generated samples "
        f"({len(set(groups))} groups), {x.shape[1]} features, L2 {args.lam}; command "
        "`python scripts/probe_category_router.py`\n"
    )
    print("| generated group (left out of the fit) | samples | misclassified % |")
    print("|---|---:|---:|")
    for name in sorted(set(groups)):
        held = group == name
        fitted = fit_logistic(x[~held], y[~held], args.lam)
        wrong = (probability(fitted, x[held]) > 0.5) != y[held].astype(bool)
        print(f"| {name} | {held.sum()} | {100 * wrong.mean():.1f} |")
    print("\n| dev set | input | shapes | misrouted, classifier | misrouted, lowest z |")
    print("|---|---|---:|---:|---:|")
    for set_name, quadruped in (("tosca", True), ("faust", False)):
        paths = real_shape_paths(args.eval_data, set_name)
        loaded = [load_shape(p) for p in paths]
        for n, noise in ((2000, 0.0), (300, 0.0), (2000, 0.01)):
            by_classifier = by_z = 0
            for k, (path, shape) in enumerate(zip(paths, loaded, strict=True)):
                local = np.random.default_rng([7, k, n])
                real: Mesh = (path.stem, shape.vertices, np.asarray(shape.faces))
                points = surface_points(real, n, noise, local)
                z = scorer(points)
                features = np.r_[geometric_features(points, local), z]
                by_classifier += (probability(model, features[None])[0] > 0.5) != quadruped
                by_z += (z[0] <= z[1]) != quadruped
            setting = f"{n} points" + (f", noise {noise}" if noise else "")
            print(f"| {set_name} | {setting} | {len(loaded)} | {by_classifier} | {by_z} |")


if __name__ == "__main__":
    main()
