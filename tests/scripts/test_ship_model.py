"""scripts/ship_model.py: one model-card writer for geodesic and matching bundles, which
regenerates the cards of the shipped bundles from their manifests (the geodesic cards were
written before the category line named the shipping commit; every other line is reproduced)."""

from __future__ import annotations

import json

import pytest

from litege_core.learned.bundle import MANIFEST, SHIPPED_DIR

SHIPPED = sorted(p.parent.name for p in SHIPPED_DIR.glob(f"*/{MANIFEST}"))


def _without_category(card: str) -> str:
    return "\n".join(line for line in card.split("\n") if not line.startswith("- **Category**"))


@pytest.mark.parametrize("name", SHIPPED)
def test_the_writer_reproduces_the_shipped_cards(name, ship_model):
    card = (SHIPPED_DIR / name / "MODEL_CARD.md").read_text()
    written = ship_model.rendered_card(SHIPPED_DIR / name)
    if "shipped at commit" in card:
        assert written == card
    else:
        assert _without_category(written) == _without_category(card)


def test_a_new_evaluation_table_replaces_the_cards(ship_model):
    card = (SHIPPED_DIR / "humans" / "MODEL_CARD.md").read_text()
    written = ship_model.rendered_card(SHIPPED_DIR / "humans", "| new | table |")
    assert "| new | table |" in written and "| new | table |" not in card
    before, after = card.split("## Evaluation")[0], written.split("## Evaluation")[0]
    assert before == after  # everything above the table is kept


def test_an_int8_basis_is_on_the_card(ship_model):
    manifest = json.loads((SHIPPED_DIR / "quadrupeds" / MANIFEST).read_text())
    assert "**Basis storage**: int8" in ship_model.model_card(manifest, basis_storage="int8")
    assert "Basis storage" not in ship_model.model_card(manifest)


def test_cards_differ_by_kind(ship_model):
    geodesic = json.loads((SHIPPED_DIR / "quadrupeds" / MANIFEST).read_text())
    matching = json.loads((SHIPPED_DIR / "quadrupeds-matching" / MANIFEST).read_text())
    card = ship_model.model_card(geodesic, "| table |")
    assert "geodesic regression" in card and "## Evaluation (`litege eval geodesic`)" in card
    assert "T-Net" not in card
    card = ship_model.model_card(matching, None, {"val": {"mean": 0.1}})
    assert "shape correspondence" in card and "## T-Net alignment error" in card
    assert "## Evaluation" not in card and card.endswith("met and missed.\n")


def test_a_continued_matching_card_names_its_start_and_its_judge(ship_model):
    manifest = json.loads((SHIPPED_DIR / "humans-matching" / MANIFEST).read_text())
    card = ship_model.model_card(manifest)
    init = manifest["training"]["init"]
    assert init["bundle"] == "humans" and "first passes" not in card
    assert f"continued from the bundle `humans` (`{init['content_hash'][:16]}`)" in card
    assert "**Frame judge**: its own networks" in card and "humans (init)'s frame" in card
    # two datasets (procedural bipeds and MakeHuman bodies on one triangulation), both credited
    assert "on 1440 generated shapes of 2 datasets (continuing `humans`)" in card
    assert "`makehuman-matching/makehuman`: MakeHuman bodies" in card
    assert "**Training shapes credit**: MakeHuman base mesh" in card
    # the same run from scratch on one procedural dataset
    training = manifest["training"]
    del training["init"], training["judge"], manifest["judge_networks"]
    training["first_passes"], training["chosen_first_pass"] = [{}, {}, {}], 0
    training["dataset"] = training["dataset"]["datasets"][0]
    card = ship_model.model_card(manifest)
    assert "3 first passes (chosen: 0)" in card and "Frame judge" not in card
    assert "on 960 procedural shapes (heat" in card
    shipped = (SHIPPED_DIR / "quadrupeds-matching" / "MODEL_CARD.md").read_text()
    assert "continued from the bundle `quadrupeds`" in shipped and "**Frame judge**" in shipped
