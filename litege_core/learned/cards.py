"""Model cards: the ``MODEL_CARD.md`` of a geodesic or matching bundle, written from its
manifest (data, configuration, training, metrics), and the card of a bundle trained on a
user's folder of meshes. Used by ``scripts/ship_model.py`` and ``litege train geodesic
--meshes``."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple


class CardFacts(NamedTuple):
    """What a model card says that depends on the kind of bundle."""

    title: str
    intended_use: str
    targets: str  # what the training targets are, after the dataset counts
    model: list[str]  # bullet lines on the descriptor, pipeline and networks
    training: str
    validation: str
    limitations: str


def _geodesic_facts(manifest: dict) -> CardFacts:
    training, metrics = manifest["training"], manifest["metrics"]
    return CardFacts(
        title=f"`{manifest['name']}` (LiteGE geodesic regression, v{manifest['version']})",
        intended_use=f"geodesic distances and paths on {manifest['category']} meshes and "
        "point clouds (300–8K points), any rotation, translation and scale. The out-of-"
        "distribution score (PCA residual z-score) flags shapes unlike the training family.",
        targets=", exact MMP ground truth; no SMAL, SURREAL, FAUST or other third-party shapes.",
        model=[
            f"- **Descriptor**: {manifest['descriptor']['n_voxels']} informative voxels, "
            f"{manifest['descriptor']['n_components']} PCA components; pipeline "
            f"{json.dumps(manifest['pipeline'])}.",
            f"- **Network**: {json.dumps(manifest['network'])}.",
        ],
        training=f"{training.get('steps')} steps × {training.get('pairs_per_step')} pairs, "
        f"{training.get('epochs')} epochs (best {training.get('best_epoch')}), "
        f"{training.get('n_train_views')} views of {training.get('n_train_shapes')} shapes, "
        f"device {training.get('device')} ({training.get('device_name')}), "
        f"{training.get('seconds', {}).get('total', 0):.0f} s, torch {training.get('torch')}; "
        f"config hash `{str(training.get('config_hash', ''))[:16]}`.",
        validation="(held-out val seeds, GT mean = 100): mean "
        f"{metrics.get('val_mean_error', float('nan')):.2f}, median "
        f"{metrics.get('val_median_error', float('nan')):.2f} over {metrics.get('val_pairs')} "
        "pairs.",
        limitations="Trained on CPU on the generated shapes listed above (validation: "
        "held-out seeds of those families, against their ground truth). Real scans unlike "
        "them (a high OOD score) have 2–3× the error of held-out generated shapes; the "
        "optional graph fusion below narrows that gap. BENCHMARKS.md has the real-shape "
        "results and where the design targets are met and missed.",
    )


def _matching_facts(manifest: dict) -> CardFacts:
    training, metrics = manifest["training"], manifest["metrics"]
    config = training.get("config", {}).get("train", {})
    seconds = sum(training.get("seconds", {}).values())
    init = training.get("init")
    return CardFacts(
        title=f"`{manifest['name']}` matching model (LiteGE shape correspondence, "
        f"v{manifest['version']})",
        intended_use=f"dense correspondence between {manifest['category']} shapes of "
        "different species and poses (meshes, broken meshes, point clouds of 500–8K points), "
        "any rotation, translation and scale: each query point of X gets the point of Y that "
        "minimizes the predicted cross-shape geodesic (coarse-to-fine search).",
        targets="; targets are the mean of the unit-area geodesics between the same template "
        "vertices on X and on Y; no SMAL, SURREAL, FAUST or other third-party shapes.",
        model=[
            "- **Pipeline**: unit-area (mesh) or calibrated Poisson-spacing scale (clouds, broken "
            f"meshes), T-Net rotation {json.dumps(manifest['tnet'])}; "
            f"{manifest['descriptor']['n_voxels']} informative voxels, "
            f"{manifest['descriptor']['n_components']} PCA components; constants "
            f"{json.dumps(manifest['pipeline'])}.",
            f"- **Networks**: {json.dumps(manifest['networks'])}; search "
            f"{json.dumps(manifest['search'])}.",
            *_tnet_swap_line(training.get("tnet_swap"), continued=bool(init)),
            *_judge_line(manifest),
        ],
        training=f"{training.get('train_views')} views ({training.get('rejected_views')} "
        f"rejected by the 0.66 rad T-Net filter), {_matching_start(training)}, then a cosine "
        f"continuation of {config.get('steps')} steps at lr {config.get('lr')}; "
        f"{seconds:.0f} s on {training.get('machine')}, torch {training.get('torch')}.",
        validation="(held-out val seeds, clean meshes, shared-source queries): matching "
        f"error ×100 {metrics.get('val_match_error_x100', float('nan')):.2f}, AUC@0.2 "
        f"{metrics.get('val_match_auc', float('nan')):.1f}.",
        limitations=f"Trained on {str(config.get('device', 'cpu')).upper()} for "
        f"{seconds / 60:.0f} min on {_training_shapes(training.get('dataset', {}))}"
        + (f" (continuing `{init['bundle']}`)" if init else "")
        + " (heat-method targets, ~2 % error) at width "
        f"{manifest['networks'][0].get('width')} and "
        f"{manifest['descriptor']['n_components']} components (the 30 MB shipping budget); see "
        "BENCHMARKS.md for where the design targets are met and missed.",
    )


def _training_shapes(dataset: dict) -> str:
    """``"N procedural shapes"`` of one dataset, ``"N generated shapes of K datasets"`` of
    several (a matching run with species datasets)."""
    parts = dataset.get("datasets")
    if parts is None:
        return f"{dataset.get('counts', {}).get('train')} procedural shapes"
    total = sum(int(part.get("counts", {}).get("train", 0)) for part in parts)
    return f"{total} generated shapes of {len(parts)} datasets"


def _matching_start(training: dict) -> str:
    """How a matching training started: a bundle it continued, or its first passes."""
    init = training.get("init")
    if init:
        return f"continued from the bundle `{init['bundle']}` (`{init['content_hash'][:16]}`)"
    return (
        f"{len(training.get('first_passes', []))} first passes (chosen: "
        f"{training.get('chosen_first_pass')})"
    )


def _judge_line(manifest: dict) -> list[str]:
    """The card line of a bundle whose frame judge has its own networks."""
    if not manifest.get("judge_networks"):
        return []
    return [
        f"- **Frame judge**: its own networks {json.dumps(manifest['judge_networks'])} "
        f"({manifest['training'].get('judge', 'kept from an earlier bundle')}): the judged "
        "frames stay the ones validated with it (BENCHMARKS.md `frame-gate`)."
    ]


def _tnet_swap_line(swap: dict | None, continued: bool = False) -> list[str]:
    """The card line of a T-Net replaced after the networks were trained
    (``scripts/swap_tnet.py``): its training run and what it replaced (in the bundle a
    ``continued`` run started from, whose continuation then trained with it)."""
    if not swap:
        return []
    where = (
        "swapped into the bundle this one continues (`scripts/swap_tnet.py`; the continuation "
        "trained with it)"
        if continued
        else "replaced after the networks were trained (`scripts/swap_tnet.py`)"
    )
    run = swap.get("tnet_training", {})
    config = run.get("config", {})
    data, train = config.get("data", {}), config.get("train", {})
    shapes = f"{data.get('n_train')} procedural shapes"
    extra = data.get("extra_category")
    if extra and data.get("n_extra_train"):
        source = COLLECTION_SOURCES_TEXT.get(extra, extra)
        credits = COLLECTION_CREDITS.get(extra)
        shapes += f" and {data['n_extra_train']} {source}" + (
            f" (credits: {credits})" if credits else ""
        )
    start = f", started from the T-Net of `{train['init']}`" if train.get("init") else ""
    return [
        f"- **T-Net**: {where}: trained on {shapes}{start}, batch {train.get('batch_size')}, best "
        f"validation step {run.get('best_step')} (mean angle "
        f"{run.get('best_val', {}).get('mean', float('nan')):.3f} rad), frame turns "
        f"{config.get('augment', {}).get('frame_turns')}; it replaced the T-Net "
        f"{json.dumps(swap.get('replaced'))} the {'first ' if continued else ''}networks were "
        "trained with."
    ]


CARD_FACTS: dict[str, Callable[[dict], CardFacts]] = {
    "geodesic": _geodesic_facts,
    "matching": _matching_facts,
}


def _training_data(dataset: dict, targets: str, init_bundle: str | None) -> list[str]:
    """The card's training-data lines: one line for a single procedural, exact-GT dataset (the
    cards of the first shipped bundles), else a line per dataset with its ground-truth solver,
    the warm start and the credits of the collection sources."""
    parts = dataset.get("datasets")
    if parts is None and dataset.get("solver") is None and dataset.get("kind") != "collection":
        return [
            f"- **Training data**: procedural `{dataset.get('name')}` shapes generated by "
            f"`litege_core.synth` ({dataset.get('counts')}){targets} Dataset manifest sha256 "
            f"`{str(dataset.get('manifest_sha256', ''))[:16]}`."
        ]
    parts = parts if parts is not None else [dataset]
    lines = [
        "- **Training data** (shapes we generate; no SMAL, SURREAL, FAUST or other third-party "
        "shapes):"
    ]
    for part in parts:
        category = str(part.get("category"))
        source = COLLECTION_SOURCES_TEXT.get(
            category, f"procedural {category}s generated by `litege_core.synth`"
        )
        solver = part.get("solver") or "exact MMP"
        lines.append(
            f"  - `{part.get('name')}`: {source} ({part.get('counts')}); ground truth: {solver}; "
            f"manifest sha256 `{str(part.get('manifest_sha256', ''))[:16]}`."
        )
    if init_bundle:
        lines.append(f"- **Warm start**: fine-tuned from the bundle `{str(init_bundle)[:16]}`.")
    categories = {str(part.get("category")) for part in parts}
    credits = sorted(COLLECTION_CREDITS[c] for c in categories if c in COLLECTION_CREDITS)
    if credits:
        lines.append(f"- **Training shapes credit**: {'; '.join(credits)}.")
    return lines


def _json_block(data: object) -> list[str]:
    return ["```json", json.dumps(data, indent=1, sort_keys=True), "```"]


COLLECTION_SOURCES_TEXT = {
    "rigged": "posed rigged animals (`litege_core.synth.rigged`: Quaternius UAA and the Khronos "
    "fox, remeshed)",
    "makehuman": "MakeHuman bodies in random shapes and poses (`litege_core.synth.makehuman`)",
    "rigged-template": "posed rigged animals of one species on one fixed remeshed triangulation "
    "(`litege_core.synth.posed_templates`: Quaternius UAA and the Khronos fox)",
    "makehuman-template": "MakeHuman bodies in random shapes and poses on one fixed remeshed "
    "triangulation (`litege_core.synth.posed_templates`)",
}
"""What a collection dataset's shapes are, by category."""

COLLECTION_CREDITS = {
    "rigged": "Ultimate Animated Animals by Quaternius (CC0); Fox: model by PixelMannen (CC0), "
    "rigging and animation by @tomkranis (CC BY 4.0), glTF conversion by @AsoboStudio and "
    "@scurest (CC BY 4.0)",
    "makehuman": "MakeHuman base mesh hm08, shape targets and skeleton (CC0)",
    "static-meshes": '"Cat" by billyd (thingiverse.com/thing:1565405), CC BY 4.0, and "Koala" by '
    "YahooJAPAN (thingiverse.com/thing:182225), CC BY 3.0, both remeshed by Oded Stein "
    "(odedstein/meshes, same licences); Spot by Keenan Crane (public domain)",
}
"""Credit lines of the collection categories (the training shapes of a bundle, the shapes of a
fusion calibration); the posed-template datasets credit the models they pose."""
COLLECTION_CREDITS["rigged-template"] = COLLECTION_CREDITS["rigged"]
COLLECTION_CREDITS["makehuman-template"] = COLLECTION_CREDITS["makehuman"]

SIDECARS_TITLE = (
    "Optional sidecars (beside the bundle files; the bundle's content hash is unchanged)"
)


def sidecar_section(directory: str | os.PathLike) -> str | None:
    """The card's section on the bundle's optional sidecars (the small head, the graph-fusion
    calibration) present in ``directory``, with the calibration data's credits; ``None`` when
    there are none."""
    from litege_core.learned.fusion import MESH_RINGS
    from litege_core.learned.fusion_calibration import FUSION_CONFIG
    from litege_core.learned.small_head import SMALL_HEAD_CONFIG

    directory = Path(directory)
    items = []
    if (directory / SMALL_HEAD_CONFIG).is_file():
        items.append(
            f"- `head-small.safetensors` + `{SMALL_HEAD_CONFIG}`: the distilled small head "
            "(issue 17): the default head of `Predictor(bundle)`, `litege geodesic` and the "
            'service (`head="auto"`); `head="full"` / `--head full` runs the trained head.'
        )
    if (directory / FUSION_CONFIG).is_file():
        data = json.loads((directory / FUSION_CONFIG).read_text())
        fitted = data.get("fitted_on") or {}
        ood = {f"{Path(d).name} (test)" for d in fitted.get("ood_datasets") or []}
        shapes = " and ".join(
            f"{n} {group} shapes"
            for group, n in (fitted.get("shapes") or {}).items()
            if group not in ood
        ) + "".join(
            f" (and {n} {group} shapes of no training family, which chose the veto's OOD limit)"
            for group, n in (fitted.get("shapes") or {}).items()
            if group in ood
        )
        items.append(
            f"- `{FUSION_CONFIG}`: the graph-fusion calibration (issue 14), read by default "
            '(`fusion="auto"` of `Predictor(bundle)`, `NumpyPredictor`, `litege geodesic` and the '
            'service); `fusion="none"` / `--fusion none` / `LITEGE_GEODESIC_FUSION=none` answer '
            "with the network alone. A mesh is answered by a Dijkstra over chords between "
            f"vertices at most {MESH_RINGS} edges apart"
            + (
                ", each that is not an edge lengthened to the arc it spans, as the vertex "
                "normals give it"
                if data.get("mesh_arcs")
                else ""
            )
            + (
                f", on a mesh whose vertex noise exceeds {data['mesh_smooth_noise']:g} of its "
                "edge length (a raw scan) after smoothing it down to that (Taubin's filter: "
                "paths follow the surface, not the noise)"
                if data.get("mesh_smooth_noise") is not None
                else ""
            )
            + (
                ", its distances divided by the graph's median over-estimate at the mesh's "
                "vertex noise, which lengthens every path"
                + (" even once smoothed" if data.get("mesh_smooth_noise") is not None else "")
                if data.get("mesh_noise_knots")
                else ""
            )
            + (
                f" (a mesh whose vertex noise exceeds {data['mesh_cloud_noise']:.2f} of its edge "
                "length is answered as the cloud of its vertices)"
                if data.get("mesh_cloud_noise") is not None
                else ""
            )
            + " (the network only between parts it "
            "cannot join); on a point cloud the network's distances are blended with a "
            + (
                f"Dijkstra over its mutual {data['mutual_k']}-nearest-neighbour graph (a chord "
                "where each end is among the other's nearest) whose "
                if data.get("mutual_k")
                else f"Dijkstra over its k = {data['k']} nearest-neighbour graph whose "
            )
            + f"edges the {data['veto_head']} head vetoes (cut where its predicted geodesic "
            f"exceeds {data['prune_ratio']} × the chord"
            + (
                f"; no veto on a cloud whose OOD z-score exceeds {data['veto_max_z']:g}, where "
                "the network's edge predictions would cut true surface edges"
                if data.get("veto_max_z") is not None
                else ""
            )
            + ")"
            + (
                " and whose chords that run along the surface normal are cut (where |n · ĉ| "
                "exceeds "
                + ", ".join(f"{c:g}" for c in data["normal_cos"])
                + " from sparse to dense clouds; 1 cuts none)"
                if data.get("normal_cos")
                else ""
            )
            + (
                ", and whose edges the learned shortcut scorer (`litege_core/models/"
                "shortcut-scorer`, trained on our procedural animals in contact poses) calls "
                "chords between touching parts are cut (above a probability of "
                + ", ".join(f"{c:g}" for c in data["shortcut_cut"])
                + " from sparse to dense clouds; 1 cuts none"
                + (
                    f"; not on a cloud rougher than {data['shortcut_max_roughness']:g}"
                    if data.get("shortcut_max_roughness") is not None
                    else ""
                )
                + ")"
                if data.get("shortcut_cut") and any(c < 1 for c in data["shortcut_cut"])
                else ""
            )
            + "; the graphs' biases and the blend "
            "weight (a sigmoid of the cloud's OOD z-score, log10 of its point count "
            "and its surface roughness) were fitted by `scripts/calibrate_fusion.py` on "
            f"{shapes} only, never on the real dev set. Constants, fit errors and the date are "
            "in the file; dev-set results in BENCHMARKS.md (`fusion-*` sections). Paths follow "
            "the same graphs (an edge-flip geodesic on a mesh, the vetoed k-NN graph's shortest "
            'path on a cloud; `route="learned"` walks the network\'s field).'
        )
        credits = [
            COLLECTION_CREDITS[c]
            for c in fitted.get("dataset_categories") or []
            if c in COLLECTION_CREDITS
        ]
        if credits:
            items.append(f"- Calibration shapes credit: {'; '.join(credits)}.")
    return "\n".join(items) if items else None


def write_sidecar_section(directory: str | os.PathLike) -> None:
    """Rewrite the sidecar section of ``DIRECTORY/MODEL_CARD.md`` from the sidecars present
    (after a small head or a fusion calibration was written beside a shipped bundle). A bundle
    with no card yet (a training run's output) is left alone: ``scripts/ship_model.py`` writes
    its card, sidecar section included."""
    path = Path(directory) / "MODEL_CARD.md"
    if not path.exists():
        return
    card = path.read_text()
    start = card.find(f"\n## {SIDECARS_TITLE}\n")
    if start >= 0:
        end = card.find("\n## ", start + 1)
        card = card[:start] + (card[end:] if end >= 0 else "\n")
    section = sidecar_section(directory)
    limitations = card.find("\n## Limitations")
    if section and limitations >= 0:
        block = f"\n## {SIDECARS_TITLE}\n\n{section}\n"
        card = card[:limitations] + block + card[limitations:]
    path.write_text(card)


def _storage_line(basis_storage: str) -> list[str]:
    if basis_storage == "float16":
        return []
    return [
        f"- **Basis storage**: {basis_storage} components with per-component scales (half the "
        "bytes of float16; `scripts/quantize_basis.py`, BENCHMARKS.md `basis-int8`)."
    ]


def model_card(
    manifest: dict,
    evaluation: str | None = None,
    tnet_report: dict | None = None,
    sidecars: str | None = None,
    basis_storage: str = "float16",
) -> str:
    """The ``MODEL_CARD.md`` of a geodesic or matching bundle, from its manifest, an optional
    evaluation table (``litege eval geodesic|matching``), for matching bundles an optional
    T-Net alignment report, the section on its sidecars (:func:`sidecar_section`) and how its
    basis stores the components (``UdfPcaBasis.component_storage``)."""
    kind = manifest.get("kind", "geodesic")
    facts = CARD_FACTS[kind](manifest)
    training = manifest["training"]
    dataset = training.get("dataset", {})
    lines = [
        f"# Model card: {facts.title}",
        "",
        f"- **Category**: {manifest['category']}; content hash `{manifest['content_hash'][:16]}`;"
        f" created {manifest['created']}, shipped at commit `{training.get('commit', 'unknown')}`.",
        *_storage_line(basis_storage),
        f"- **Intended use**: {facts.intended_use}",
        *_training_data(dataset, facts.targets, training.get("init_bundle")),
        *facts.model,
        f"- **Training**: {facts.training}",
        f"- **Validation** {facts.validation}",
    ]
    if tnet_report:
        title = "T-Net alignment error (rad) of the bundle's own T-Net (`scripts/tnet_report.py`)"
        lines += ["", f"## {title}", "", *_json_block(tnet_report)]
    lines += ["", "## Training configuration", "", *_json_block(training.get("config", {}))]
    if evaluation:
        lines += ["", f"## Evaluation (`litege eval {kind}`)", "", evaluation.strip()]
    if sidecars:
        lines += ["", f"## {SIDECARS_TITLE}", "", sidecars.strip()]
    lines += ["", "## Limitations", "", facts.limitations]
    return "\n".join(lines) + "\n"


def collection_model_card(
    manifest: dict, comparison: str, collection: dict, credits: str | None = None
) -> str:
    """The ``MODEL_CARD.md`` of a geodesic bundle trained on a user's folder of meshes
    (``litege train geodesic --meshes``): the geodesic card's model and training facts, the
    collection it was trained on (``collection``: ``meshes``, ``files`` and ``shapes`` per
    split, ``solver``, ``augmentation``, ``init``), the held-out comparison table (this bundle
    vs the reference model(s) vs heat vs kNN) and the folder's credits, if any."""
    facts = _geodesic_facts(manifest)
    training = manifest["training"]
    files, shapes = collection.get("files", {}), collection.get("shapes", {})
    init = collection.get("init")
    lines = [
        f"# Model card: {facts.title}",
        "",
        f"- **Category**: {manifest['category']}; content hash `{manifest['content_hash'][:16]}`;"
        f" created {manifest['created']} by `litege train geodesic --meshes`"
        f" (litege {training.get('litege')}).",
        "- **Intended use**: geodesic distances and paths on shapes like those of the "
        "collection below (meshes and point clouds of 300–8K points, any rotation, translation "
        "and scale). The out-of-distribution score flags shapes unlike the collection.",
        f"- **Training data**: the mesh files of `{collection.get('meshes')}`, split by file "
        f"(seed {collection.get('seed')}): {files.get('train')} train / {files.get('val')} val / "
        f"{files.get('test')} held-out test files; {shapes.get('train')} / {shapes.get('val')} / "
        f"{shapes.get('test')} augmented remeshes (smooth stretches, isotropic remeshing: "
        f"`{collection.get('augmentation')}`) with {collection.get('solver')} ground truth; "
        "training views add rotations, resampling (300–8K points), noise and cuts. Dataset "
        f"manifest sha256 `{str(training.get('dataset', {}).get('manifest_sha256', ''))[:16]}`.",
        "- **Starting point**: "
        + (
            f"fine-tuned from `{init}`."
            if init
            else "trained from scratch (basis fitted on the training files)."
        ),
        *facts.model,
        f"- **Training**: {facts.training}",
        f"- **Validation** (val files, GT mean = 100): mean "
        f"{manifest['metrics'].get('val_mean_error', float('nan')):.2f}, median "
        f"{manifest['metrics'].get('val_median_error', float('nan')):.2f}.",
        "",
        "## Held-out comparison (test files, never trained on nor used for selection)",
        "",
        "Mean error (median), ground truth rescaled to mean 100 per setting "
        "(`litege_core.evaluation.geodesic.evaluate_methods`).",
        "",
        comparison.strip(),
        "",
        "## Training configuration",
        "",
        *_json_block(training.get("config", {})),
    ]
    if credits:
        lines += ["", "## Credits of the training meshes", "", credits.strip()]
    lines += [
        "",
        "## Limitations",
        "",
        "Trained on a small collection under a time budget: expect it to work on shapes like "
        "the collection's, and check the out-of-distribution score on anything else. The "
        "held-out numbers come from a few files only.",
    ]
    return "\n".join(lines) + "\n"


__all__ = ["CARD_FACTS", "CardFacts", "collection_model_card", "model_card"]
