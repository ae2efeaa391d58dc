"""The model card's sidecar section (``litege_core.learned.cards``): written from the sidecar
files present, rewritten in place when they change, gone when they are."""

from __future__ import annotations

import json
import shutil

from litege_core.learned.bundle import SHIPPED_DIR
from litege_core.learned.cards import SIDECARS_TITLE, sidecar_section, write_sidecar_section
from litege_core.learned.fusion_calibration import FUSION_CONFIG
from litege_core.learned.small_head import SMALL_HEAD_CONFIG

CARD = "# Model card: toy\n\n- facts\n\n## Evaluation\n\ntable\n\n## Limitations\n\nsmall\n"


def test_the_section_follows_the_sidecar_files(tmp_path) -> None:
    (tmp_path / "MODEL_CARD.md").write_text(CARD)
    assert sidecar_section(tmp_path) is None
    write_sidecar_section(tmp_path)
    assert (tmp_path / "MODEL_CARD.md").read_text() == CARD

    fusion = json.loads((SHIPPED_DIR / "quadrupeds" / FUSION_CONFIG).read_text())
    fusion["fitted_on"]["dataset_categories"] = ["rigged", "static-meshes"]
    (tmp_path / FUSION_CONFIG).write_text(json.dumps(fusion))
    write_sidecar_section(tmp_path)
    card = (tmp_path / "MODEL_CARD.md").read_text()
    head, _, rest = card.partition(f"## {SIDECARS_TITLE}\n\n")
    section, _, tail = rest.partition("\n\n## Limitations")
    assert head == CARD.split("## Limitations")[0] and tail == "\n\nsmall\n"
    fitted = json.loads((tmp_path / FUSION_CONFIG).read_text())["fitted_on"]
    assert all(f"{n} {group} shapes" in section for group, n in fitted["shapes"].items())
    assert "Quaternius (CC0)" in section and "@tomkranis (CC BY 4.0)" in section
    assert '"Cat" by billyd' in section and "YahooJAPAN" in section  # CC BY calibration meshes
    assert "head-small" not in section
    # normal limits are named where the calibration has them
    for limits in ([0.9, 0.8, 0.7, 0.7, 0.6], []):
        (tmp_path / FUSION_CONFIG).write_text(json.dumps({**fusion, "normal_cos": limits}))
        named = "exceeds 0.9, 0.8, 0.7, 0.7, 0.6 from sparse" in sidecar_section(tmp_path)
        assert named == bool(limits)
    # so is the mutual k-NN graph
    for mutual in (24, 0):
        (tmp_path / FUSION_CONFIG).write_text(json.dumps({**fusion, "mutual_k": mutual}))
        section = sidecar_section(tmp_path)
        assert ("mutual 24-nearest-neighbour graph" in section) == bool(mutual)
        assert ("k = 16 nearest-neighbour graph" in section) == (not mutual)
    # and the veto's OOD limit, with the shapes that chose it apart
    ood = {
        **fusion,
        "fitted_on": {
            **fusion["fitted_on"],
            "shapes": {"folder-cal (test)": 24, "primitives-cal (test)": 24},
            "ood_datasets": ["data/primitives-cal"],
        },
    }
    (tmp_path / FUSION_CONFIG).write_text(json.dumps(ood))
    assert (
        "on 24 folder-cal (test) shapes (and 24 primitives-cal (test) shapes of no training "
        "family, which chose the veto's OOD limit) only" in sidecar_section(tmp_path)
    )
    for limit in (4.0, None):
        (tmp_path / FUSION_CONFIG).write_text(json.dumps({**fusion, "veto_max_z": limit}))
        named = "no veto on a cloud whose OOD z-score exceeds 4," in sidecar_section(tmp_path)
        assert named == (limit is not None)
    # and a mesh bias that follows the vertex noise
    for knots in ([0.02, 0.1], []):
        noisy = {**fusion, "mesh_noise_knots": knots, "mesh_noise_bias": [1.01] * len(knots)}
        (tmp_path / FUSION_CONFIG).write_text(json.dumps(noisy))
        named = "over-estimate at the mesh's vertex noise" in sidecar_section(tmp_path)
        assert named == bool(knots)
    # and the learned shortcut cut, with its roughness limit
    for cuts, rough in (([1.0, 1.0, 0.3, 0.2, 0.2], 0.25), ([1.0] * 5, None), ([], None)):
        cutting = {**fusion, "shortcut_cut": cuts, "shortcut_max_roughness": rough}
        (tmp_path / FUSION_CONFIG).write_text(json.dumps(cutting))
        section = sidecar_section(tmp_path)
        named = "probability of 1, 1, 0.3, 0.2, 0.2 from sparse to dense" in section
        assert named == (0.3 in cuts)
        assert ("not on a cloud rougher than 0.25" in section) == (0.3 in cuts)
    for limit in (0.45, None):
        (tmp_path / FUSION_CONFIG).write_text(json.dumps({**fusion, "mesh_cloud_noise": limit}))
        named = "noise exceeds 0.45 of its edge length" in sidecar_section(tmp_path)
        assert named == (limit is not None)
    (tmp_path / FUSION_CONFIG).write_text(json.dumps(fusion))

    (tmp_path / SMALL_HEAD_CONFIG).write_text("{}")
    write_sidecar_section(tmp_path)
    write_sidecar_section(tmp_path)  # idempotent
    card = (tmp_path / "MODEL_CARD.md").read_text()
    assert card.count(SIDECARS_TITLE) == 1 and "the distilled small head" in card

    for name in (FUSION_CONFIG, SMALL_HEAD_CONFIG):
        (tmp_path / name).unlink()
    write_sidecar_section(tmp_path)
    assert (tmp_path / "MODEL_CARD.md").read_text() == CARD


def test_a_card_names_every_dataset_its_solver_the_warm_start_and_the_credits() -> None:
    from litege_core.learned.cards import model_card

    manifest = json.loads((SHIPPED_DIR / "quadrupeds" / "manifest.json").read_text())
    # the first shipped bundles: one procedural dataset with exact ground truth, no warm start
    manifest["training"]["dataset"] = {
        "name": "quadruped-large",
        "category": "quadruped",
        "counts": {"train": 2200, "val": 100, "test": 100},
        "manifest_sha256": "e" * 64,
    }
    manifest["training"].pop("init_bundle", None)
    single = model_card(manifest)
    assert "- **Training data**: procedural `quadruped-large`" in single
    assert "Warm start" not in single
    manifest["training"]["dataset"] = {
        "datasets": [
            {
                "name": "quadruped-heat",
                "category": "quadruped",
                "kind": "template",
                "counts": {"train": 416, "val": 48, "test": 48},
                "manifest_sha256": "a" * 64,
                "solver": "heat method (t_coef=1)",
            },
            {
                "name": "rigged-heat",
                "category": "rigged",
                "kind": "collection",
                "counts": {"train": 1500, "val": 120, "test": 120},
                "manifest_sha256": "b" * 64,
                "solver": "heat method (t_coef=0.35)",
            },
        ],
        "manifest_sha256": "c" * 64,
    }
    manifest["training"]["init_bundle"] = "d" * 64
    card = model_card(manifest)
    assert "`quadruped-heat`: procedural quadrupeds" in card
    assert "`rigged-heat`: posed rigged animals" in card
    assert "ground truth: heat method (t_coef=1)" in card
    assert "ground truth: heat method (t_coef=0.35)" in card
    assert "**Warm start**: fine-tuned from the bundle `dddddddddddddddd`" in card
    assert "@tomkranis (CC BY 4.0)" in card  # the Khronos fox's rig is CC BY


def test_a_bundle_without_a_card_is_left_alone(tmp_path) -> None:
    shutil.copyfile(SHIPPED_DIR / "quadrupeds" / FUSION_CONFIG, tmp_path / FUSION_CONFIG)
    write_sidecar_section(tmp_path)  # a training run's bundle: the card comes when it ships
    assert not (tmp_path / "MODEL_CARD.md").exists()


def test_a_matching_card_says_when_its_t_net_was_replaced() -> None:
    from litege_core.learned.cards import model_card

    manifest = json.loads((SHIPPED_DIR / "quadrupeds-matching" / "manifest.json").read_text())
    manifest["training"].pop("tnet_swap", None)
    assert "replaced after the networks were trained" not in model_card(manifest)
    manifest["training"]["tnet_swap"] = {
        "source": "out/tnet-gpu-a/tnet.safetensors",
        "replaced": manifest["tnet"],
        "tnet_training": {
            "best_step": 4000,
            "best_val": {"mean": 0.5624},
            "config": {
                "data": {"n_train": 5000},
                "train": {"batch_size": 144},
                "augment": {"frame_turns": True},
            },
        },
    }
    card = model_card(manifest)
    assert "trained on 5000 procedural shapes, batch 144, best validation step 4000" in card
    assert "(mean angle 0.562 rad), frame turns True" in card
    assert "started from" not in card and "credits" not in card

    config = manifest["training"]["tnet_swap"]["tnet_training"]["config"]
    config["data"].update(extra_category="rigged", n_extra_train=800)
    config["train"]["init"] = "quadrupeds"
    card = model_card(manifest)
    assert "trained on 5000 procedural shapes and 800 posed rigged animals" in card
    assert "CC BY 4.0" in card  # the rigged fox's authors are credited
    assert "started from the T-Net of `quadrupeds`, batch 144" in card
