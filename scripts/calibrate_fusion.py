"""Fit a geodesic bundle's graph-fusion calibration on shapes we generate (never the dev set).

Usage: python scripts/calibrate_fusion.py --model quadrupeds [--synthetic 16]
    [--dataset data/rigged-cal ...] [--sources 12] [--prune-ratio 1.3,1.6]
    [--normal-cos 1.0,0.9,0.8,0.7,0.6] [--mutual-k 0,24] [--mesh-arcs 0,1]
    [--mesh-smooth-noise 0.08]
    [--ood-dataset data/primitives-cal]
    [--veto-max-z 1,2,3,4,6,8] [--ood-gate-tolerance 0]
    [--shortcut-cut 1,0.7,0.5,0.3] [--shortcut-max-roughness none,0.2,0.3] [--write]

Calibration shapes: ``--synthetic`` held-out procedural shapes of the bundle's category
(generated on the fly, exact rows cached under ``--cache``) and the test split of every
``--dataset`` (collection datasets such as the rigged animals or MakeHuman bodies of
``docs/jobs.md``, first ``--sources`` rows each). Prints the fitted constants and a table of
network / pruned graph / fused errors per setting (each density's normal limit is the
candidate whose graph errs least there; ``--normal-cos 1`` fits none; of the ``--prune-ratio``
and ``--mutual-k`` candidates, the pair whose fit has the lowest mean fused error is kept; of the
``--mesh-arcs`` candidates (a mesh's ring graph with plain chords, 0, or chords lengthened to
their arcs, 1), the one whose bias-corrected clean-mesh rows err least (``choose_mesh_arcs``;
the noisy meshes of the ``meshnoise_S`` settings give that graph's bias its noise knots,
``mesh_noise_knots``, and, answered also as the clouds of their vertices by the fitted fusion,
the noise above which a mesh is answered so, ``choose_mesh_cloud_noise``: the last step, only
with ``--mesh-smooth-noise none``; by default a mesh noisier than that limit is smoothed down
to it before its graph, and the knots are its noise before smoothing and its smoothed graph's
bias); then
the OOD limit of the network veto, of the ``--veto-max-z`` candidates or none, whose fusion has
the lowest mean fused error (within 1 %), never below the highest OOD z-score of the other
calibration shapes. The test split of every ``--ood-dataset`` (shapes of no training family,
e.g. ``data/primitives-cal`` of ``scripts/build_folder_cal.py --primitives``) joins only the
last two steps: these shapes choose the limit, and with ``--ood-gate-tolerance`` above 0 the
gate is then refitted to lower their mean fused error while the other calibration clouds' stays
within that fraction of their own fit (:func:`~litege_core.evaluation.fusion.fit_gate_with_ood`;
the default, 0, keeps the gate of the other shapes: the refit cost the real dev humans); every
other constant is that of the ``--dataset`` and synthetic shapes);
With ``--shortcut-cut`` candidates below 1, the learned shortcut scorer
(:mod:`litege_core.learned.shortcuts`, the shipped weights) cuts the fitted cloud graph: per
clean-cloud density the candidate whose graph errs least (1: no cut), then, of the
``--shortcut-max-roughness`` candidates, the roughness above which clouds stay uncut whose
refitted fusion has the lowest mean fused error (the other constants are those of the uncut
fit; the veto limit is chosen after it);
``--write`` stores
``fusion.json`` beside the bundle files (``Predictor(bundle, fusion="graph")`` reads it) and
rewrites the model card's sidecar section.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from datetime import UTC, datetime
from pathlib import Path

import torch

from litege_core.evaluation.fusion import (
    CALIBRATION_SETTINGS,
    DEFAULT_K,
    DEFAULT_MESH_SMOOTH_NOISE,
    MESH_ARCS_CANDIDATES,
    MUTUAL_K_CANDIDATES,
    NORMAL_COS_CANDIDATES,
    PRUNE_RATIO_CANDIDATES,
    SHORTCUT_CUT_CANDIDATES,
    VETO_MAX_Z_CANDIDATES,
    choose_cut_roughness,
    choose_mesh_arcs,
    choose_mesh_cloud_noise,
    choose_normal_limits,
    choose_shortcut_cuts,
    choose_veto_limit,
    collect_cut_samples,
    collect_ood_samples,
    collect_samples,
    fit_fusion,
    fit_gate_with_ood,
    fusion_summary,
    fusion_table,
    is_clean_mesh,
    mean_fused_error,
    with_cloud_rows,
)
from litege_core.evaluation.geodesic import (
    dataset_eval_shapes,
    generated_eval_shapes,
    is_mesh_setting,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import Predictor, load_model
from litege_core.learned.cards import write_sidecar_section
from litege_core.learned.fusion import MESH_RINGS
from litege_core.learned.fusion_calibration import FusionCalibration, save_fusion
from litege_core.learned.shortcuts import shortcut_scorer_sha256
from litege_core.learned.small_head import small_head_config
from litege_core.synth import CATEGORIES


def dataset_category(directory: str) -> str:
    """The category of a dataset directory (its manifest's spec), e.g. ``rigged``."""
    manifest = json.loads((Path(directory) / "manifest.json").read_text())
    return str(manifest["spec"]["category"])


def test_shapes(datasets: list[str], sources: int) -> list:
    """The test-split shapes of ``datasets`` with their first ``sources`` exact rows."""
    return [
        dataclasses.replace(s, sources=s.sources[:sources], gt=s.gt[:sources])
        for dataset in datasets
        for s in dataset_eval_shapes(dataset, "test", group=f"{Path(dataset).name} (test)")
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="quadrupeds", help="shipped name or bundle dir")
    parser.add_argument("--synthetic", type=int, default=16)
    parser.add_argument(
        "--dataset",
        action="append",
        default=[],
        help="calibration dataset (its test split; a collection or template dataset)",
    )
    parser.add_argument(
        "--ood-dataset",
        action="append",
        default=[],
        help="dataset of shapes unlike the training families (its test split): they choose the "
        "veto's OOD limit and refit the gate within --ood-gate-tolerance",
    )
    parser.add_argument(
        "--ood-gate-tolerance",
        type=float,
        default=0.0,
        help="fraction of the other calibration clouds' mean fused error the gate may give up "
        "for the --ood-dataset shapes (default 0: no refit; BENCHMARKS ood-gate)",
    )
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--k", type=int, default=DEFAULT_K)
    parser.add_argument(
        "--prune-ratio",
        default=",".join(str(r) for r in PRUNE_RATIO_CANDIDATES),
        help="comma-separated candidates: the one whose fit has the lowest mean fused error on "
        "the calibration shapes is kept",
    )
    parser.add_argument(
        "--normal-cos",
        default=",".join(str(c) for c in NORMAL_COS_CANDIDATES),
        help="comma-separated normal limits (1: none): each density keeps the one whose graph "
        "has the lowest error on the calibration shapes",
    )
    parser.add_argument(
        "--mutual-k",
        default=",".join(str(m) for m in MUTUAL_K_CANDIDATES),
        help="comma-separated cloud-graph candidates (0: symmetric k-NN; M: mutual k-NN of M "
        "neighbours); with the prune ratio, the pair whose fit has the lowest mean fused error "
        "is kept",
    )
    parser.add_argument(
        "--mesh-arcs",
        default=",".join(str(int(a)) for a in MESH_ARCS_CANDIDATES),
        help="comma-separated mesh-graph candidates (0: plain chords; 1: chords lengthened to "
        "their arcs); the one whose bias-corrected mesh rows err least is kept",
    )
    parser.add_argument(
        "--mesh-smooth-noise",
        default=f"{DEFAULT_MESH_SMOOTH_NOISE:g}",
        help="vertex noise above which a mesh is smoothed down to it before its graph "
        "(none: the mesh as it is, and a noise above which it is answered as a cloud is chosen)",
    )
    parser.add_argument(
        "--veto-max-z",
        default=",".join(f"{z:g}" for z in VETO_MAX_Z_CANDIDATES),
        help="comma-separated OOD z-scores above which to try the network veto off (empty: "
        "the veto on every cloud); the one whose fusion has the lowest mean fused error, or "
        "none, is kept",
    )
    parser.add_argument(
        "--veto-head",
        choices=("auto", "small", "full"),
        default="auto",
        help="head that prunes the graph (auto: the small head where the bundle ships one)",
    )
    parser.add_argument(
        "--network",
        choices=("full", "default"),
        default="full",
        help="the network the fusion blends: full (the trained head on the full lattice) or "
        "default (the configuration a Predictor runs by default: the small head on the stride2 "
        "lattice where the bundle has them)",
    )
    parser.add_argument(
        "--shortcut-cut",
        default=",".join(f"{c:g}" for c in SHORTCUT_CUT_CANDIDATES),
        help="cuts of the shipped shortcut scorer to try per density (1: none)",
    )
    parser.add_argument(
        "--shortcut-max-roughness",
        default="none",
        help="roughness limits of the cut to try ('none': every cloud is cut)",
    )
    parser.add_argument("--settings", default=",".join(CALIBRATION_SETTINGS))
    parser.add_argument("--cache", default="out/diagnose/cache", help="exact-row cache")
    parser.add_argument("--write", action="store_true", help="write fusion.json into the bundle")
    args = parser.parse_args()
    torch.set_num_threads(1)
    start = time.perf_counter()
    bundle = load_model(args.model)
    configuration = "full" if args.network == "full" else "auto"
    predictor = Predictor(  # the network alone
        bundle, head=configuration, descriptor_lattice=configuration, fusion="none"
    )
    veto_head = args.veto_head
    if veto_head == "auto":
        veto_head = "full" if small_head_config(bundle) is None else "small"
    category = bundle.manifest.get("category")
    if category not in CATEGORIES:
        raise SystemExit(f"bundle category {category!r} has no procedural families")
    shapes = generated_eval_shapes(category, args.synthetic, args.sources, cache_dir=args.cache)
    shapes += test_shapes(args.dataset, args.sources)
    ood_shapes = test_shapes(args.ood_dataset, args.sources)
    settings = tuple(args.settings.split(","))
    groups = sorted({s.group for s in shapes + ood_shapes})
    fitted_on = {
        "shapes": {g: sum(s.group == g for s in shapes + ood_shapes) for g in groups},
        "settings": list(settings),
        "sources_per_shape": args.sources,
        "datasets": args.dataset,
        "ood_datasets": args.ood_dataset,
        "dataset_categories": [dataset_category(d) for d in args.dataset + args.ood_dataset],
        "date": f"{datetime.now(UTC):%Y-%m-%d}",
    }
    ratios = sorted(float(r) for r in args.prune_ratio.split(","))
    limits = sorted(float(c) for c in args.normal_cos.split(","))
    mutuals = sorted(int(m) for m in args.mutual_k.split(","))
    arcs_tried = sorted({bool(int(a)) for a in args.mesh_arcs.split(",")})
    smooth = None if args.mesh_smooth_noise == "none" else float(args.mesh_smooth_noise)
    mesh_settings = [s for s in settings if is_mesh_setting(s)]
    by_arcs = {  # one variant: the mesh graph does not depend on the cloud graph's
        arcs: next(
            iter(
                collect_samples(
                    predictor,
                    shapes,
                    mesh_settings,
                    k=args.k,
                    veto_head=veto_head,
                    mesh_arcs=arcs,
                    mesh_smooth_noise=smooth,
                ).values()
            )
        )
        for arcs in arcs_tried
    }
    clean_meshes = {  # the graph is chosen on clean meshes; noise moves its bias only
        arcs: [s for s in samples if is_clean_mesh(s)] for arcs, samples in by_arcs.items()
    }
    chosen = any(clean_meshes.values())
    mesh_arcs, arcs_errors = choose_mesh_arcs(clean_meshes) if chosen else (False, {})
    by_variant = collect_samples(
        predictor,
        shapes,
        [s for s in settings if not is_mesh_setting(s)],
        k=args.k,
        prune_ratios=ratios,
        normal_limits=limits,
        mutual_ks=mutuals,
        veto_head=veto_head,
    )
    meshes = by_arcs.get(mesh_arcs, [])
    by_variant = {key: [*meshes, *clouds] for key, clouds in by_variant.items()}
    candidates = []  # (mean fused error, (prune ratio, mutual k), samples, calibration)
    for prune_ratio in ratios:
        for mutual in mutuals:
            chosen, samples = choose_normal_limits(
                {limit: by_variant[(prune_ratio, limit, mutual)] for limit in limits}
            )
            calibration = fit_fusion(
                samples,
                bundle.content_hash,
                k=args.k,
                prune_ratio=prune_ratio,
                veto_head=veto_head,
                fitted_on=fitted_on,
                normal_cos=chosen if limits != [1.0] else None,
                mutual_k=mutual,
                mesh_arcs=mesh_arcs,
                mesh_smooth_noise=smooth,
            )
            error = mean_fused_error(samples, calibration)
            candidates.append((error, (prune_ratio, mutual), samples, calibration, chosen))
    _, _, samples, calibration, normal_limits = min(candidates, key=lambda c: c[0])
    cuts = sorted(float(c) for c in args.shortcut_cut.split(","))
    roughness_errors: dict = {}
    chosen_cuts: dict[str, float] = {}
    if any(c < 1.0 for c in cuts):
        sha256 = shortcut_scorer_sha256()
        cloud_settings = [s for s in settings if not is_mesh_setting(s)]
        meshes = [s for s in samples if s.mesh]
        by_cut = {
            cut: [*meshes, *clouds]
            for cut, clouds in collect_cut_samples(
                predictor, shapes, calibration, [c for c in cuts if c < 1.0], sha256,
                cloud_settings,
            ).items()
        }  # fmt: skip
        by_cut[1.0] = samples
        chosen_cuts, cut_samples = choose_shortcut_cuts(by_cut)
        roughness = [
            None if r == "none" else float(r) for r in args.shortcut_max_roughness.split(",")
        ]

        def refit(merged: list, limit: float | None) -> FusionCalibration:
            return fit_fusion(
                merged,
                bundle.content_hash,
                k=calibration.k,
                prune_ratio=calibration.prune_ratio,
                veto_head=veto_head,
                fitted_on=fitted_on,
                normal_cos=normal_limits if limits != [1.0] else None,
                mutual_k=calibration.mutual_k,
                mesh_arcs=mesh_arcs,
                mesh_smooth_noise=smooth,
                shortcut_cut=chosen_cuts,
                shortcut_scorer=sha256,
                shortcut_max_roughness=limit,
            )

        _, samples, calibration, roughness_errors = choose_cut_roughness(
            samples, cut_samples, roughness, refit
        )
    limits_tried = [float(z) for z in args.veto_max_z.split(",") if z.strip()]
    floor = max((s.z_score for s in samples if not s.mesh), default=-math.inf)
    n_kind = len(samples)
    samples += collect_ood_samples(predictor, ood_shapes, calibration, settings)
    calibration, samples, veto_errors = choose_veto_limit(samples, calibration, limits_tried, floor)
    kind_gate = calibration.gate
    if args.ood_gate_tolerance > 0:
        gate = fit_gate_with_ood(
            samples[:n_kind], samples[n_kind:], calibration, args.ood_gate_tolerance
        )
        calibration = dataclasses.replace(calibration, gate=gate)
    cloud_errors: dict = {}
    if smooth is None and any(s.mesh and not is_clean_mesh(s) for s in samples[:n_kind]):
        kind = with_cloud_rows(predictor, shapes, samples[:n_kind], calibration)
        limit, cloud_errors = choose_mesh_cloud_noise(kind, calibration)
        calibration = dataclasses.replace(calibration, mesh_cloud_noise=limit)
        samples = kind + samples[n_kind:]
    summary = fusion_summary(samples, calibration)
    counts = ", ".join(f"{g}: {n}" for g, n in fitted_on["shapes"].items())
    print(f"### Graph fusion calibration: `{bundle.name}`\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; "
        f"{len(shapes)} calibration shapes ({counts}), "
        f"{args.sources} FPS sources each, exact rows, unit area, GT mean 100; "
        f"{time.perf_counter() - start:.0f} s; command `python scripts/calibrate_fusion.py "
        f"--model {args.model} --synthetic {args.synthetic} "
        + " ".join(f"--dataset {d}" for d in args.dataset)
        + "".join(f" --ood-dataset {d}" for d in args.ood_dataset)
        + f" --sources {args.sources} --prune-ratio {args.prune_ratio}"
        + f" --normal-cos {args.normal_cos} --mutual-k {args.mutual_k}"
        + f" --mesh-arcs {args.mesh_arcs} --mesh-smooth-noise {args.mesh_smooth_noise}"
        + f" --veto-max-z {args.veto_max_z} --ood-gate-tolerance {args.ood_gate_tolerance:g}"
        + f" --shortcut-cut {args.shortcut_cut}"
        + f" --shortcut-max-roughness {args.shortcut_max_roughness}"
        + (f" --settings {args.settings}" if settings != CALIBRATION_SETTINGS else "")
        + "`"
    )
    knots = ", ".join(
        f"{10**x:.0f} pts: {b:.4f}"
        for x, b in zip(calibration.bias_log10_points, calibration.bias, strict=True)
    )
    normal = (
        ", ".join(
            f"{10**x:.0f} pts: {c:g}"
            for x, c in zip(calibration.bias_log10_points, calibration.normal_cos, strict=True)
        )
        if calibration.normal_cos
        else "none"
    )
    a, c_z, c_n, c_r = calibration.gate
    print(
        f"- graph of a cloud: k = {calibration.k}, edges cut above {calibration.prune_ratio} "
        f"× chord (predicted by the {veto_head} head) and chords with |n·ĉ| above the normal "
        f"limit ({normal}); "
        + (
            f"mutual k-NN graph of {calibration.mutual_k} neighbours; "
            if calibration.mutual_k
            else ""
        )
        + (
            f"no network veto above OOD z = {calibration.veto_max_z:g}; "
            if calibration.veto_max_z is not None
            else ""
        )
        + f"median graph / geodesic: {knots}; "
        f"network weight = sigmoid({a:.3f} + {c_z:.3f}·z + {c_n:.3f}·(log10 N − 3) "
        f"+ {c_r:.3f}·roughness)\n"
        f"- graph of a mesh: chords between vertices at most {MESH_RINGS} edges apart"
        + (", lengthened to their arcs" if calibration.mesh_arcs else "")
        + (
            f", smoothed first where its vertex noise exceeds {calibration.mesh_smooth_noise:g}"
            if calibration.mesh_smooth_noise is not None
            else ""
        )
        + f"; median graph / geodesic {calibration.mesh_bias:.4f} (the graph alone)"
        + (
            f"; a mesh of vertex noise above {calibration.mesh_cloud_noise:.3f} is answered as "
            "the cloud of its vertices"
            if calibration.mesh_cloud_noise is not None
            else ""
        )
        + (
            "; with vertex noise ν: "
            + ", ".join(
                f"ν {x:.3f}: {b:.4f}"
                for x, b in zip(
                    calibration.mesh_noise_knots, calibration.mesh_noise_bias, strict=True
                )
            )
            if calibration.mesh_noise_knots
            else ""
        )
        + "\n"
    )
    if cloud_errors:
        tried = ", ".join(
            f"{'none' if v is None else f'{v:.3f}'}: {error:.3f}"
            for v, error in cloud_errors.items()
        )
        print(
            "- vertex noise above which a mesh is answered as the cloud of its vertices "
            f"(mean fused error of the calibration meshes): {tried}\n"
        )
    if len(arcs_errors) > 1:
        tried = ", ".join(
            f"{'arcs' if arcs else 'chords'}: {error:.3f}" for arcs, error in arcs_errors.items()
        )
        print(f"- mesh graph candidates (mean bias-corrected error of the meshes): {tried}\n")
    if len(candidates) > 1:
        tried = ", ".join(
            f"{ratio} / {mutual}: {error:.3f}" for error, (ratio, mutual), *_ in candidates
        )
        print(
            "- prune ratio / mutual k candidates (mean fused error over all calibration "
            f"inputs): {tried}\n"
        )
    if chosen_cuts:
        per_density = ", ".join(
            f"{setting}: {cut:g}" for setting, cut in sorted(chosen_cuts.items())
        )
        tried = ", ".join(
            f"{'none' if r is None else f'{r:g}'}: {error:.3f}"
            for r, error in roughness_errors.items()
        )
        print(
            f"- learned shortcut cut (scorer {calibration.shortcut_scorer[:12] or 'none'}; "
            f"candidates {args.shortcut_cut}), chosen per clean-cloud density by the graph's "
            f"error: {per_density}; roughness limit candidates (mean fused error over all "
            f"calibration inputs): {tried}\n"
        )
    if veto_errors:
        tried = ", ".join(
            f"{'none' if z is None else f'{z:g}'}: {error:.3f}" for z, error in veto_errors.items()
        )
        print(
            f"- veto OOD limit candidates at or above {floor:.2f}, the highest z-score of the "
            "calibration shapes of the model's kind (mean fused error over the calibration "
            f"clouds): {tried}\n"
        )
    if calibration.gate != kind_gate:
        kind = dataclasses.replace(calibration, gate=kind_gate)
        before = (
            mean_fused_error(samples[:n_kind], kind),
            mean_fused_error(samples[n_kind:], kind),
        )
        after = (
            mean_fused_error(samples[:n_kind], calibration),
            mean_fused_error(samples[n_kind:], calibration),
        )
        shown = ", ".join(f"{v:.3f}" for v in kind_gate)
        print(
            "- gate refitted with the --ood-dataset shapes "
            f"(tolerance {args.ood_gate_tolerance:g}): "
            f"from ({shown}); mean fused error of the other calibration inputs "
            f"{before[0]:.3f} → {after[0]:.3f}, of the --ood-dataset inputs "
            f"{before[1]:.3f} → {after[1]:.3f}\n"
        )
        fitted_on["gate_without_ood"] = list(kind_gate)
    fitted_on["errors"] = summary
    print(fusion_table(summary, calibration.k))
    if args.write:
        if bundle.path is None:
            raise SystemExit("the bundle has no directory to write fusion.json into")
        written = save_fusion(bundle.path, dataclasses.replace(calibration, fitted_on=fitted_on))
        write_sidecar_section(bundle.path)
        shown = os.path.relpath(written)  # a path of the repository, not of this machine
        print(f"\nwrote {shown} and the sidecar section of the model card")


if __name__ == "__main__":
    main()
