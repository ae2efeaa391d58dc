"""``litege train geodesic --meshes DIR``: a folder of meshes → a served bundle with its model
card, the trainer's wall-clock budget, the data budget and the topology check of matching."""

import json
import time
import types

import numpy as np
import pytest
import trimesh

from litege_core.cli import main
from litege_core.datasets import build as build_module
from litege_core.errors import InputError
from litege_core.learned import load_bundle
from litege_core.train import trainer as trainer_module
from litege_core.train.from_meshes import (
    BudgetedFactory,
    DataBudgetReached,
    check_folder,
    folder_config,
    plan_schedule,
    shared_topology,
)
from litege_core.train.pipeline import prepare_run

from .conftest import edge_dijkstra

TINY = """
[data]
views_per_shape = 2
clean_samples = 300
val_sources = 4
val_targets = 32
[augment]
min_points = 200
max_points = 600
[train]
batch_views = 4
sources_per_view = 4
targets_per_view = 8
epochs = 2
steps_per_epoch = 15
device = "cpu"
"""


def _blob(index: int, subdivisions: int = 3) -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(index)
    vertices = np.asarray(sphere.vertices) * [1.4 + 0.1 * index, 1.0, 0.7]
    vertices = vertices + 0.1 * np.sin(3 * vertices[:, [1, 2, 0]] + rng.uniform(0, 6, 3))
    return trimesh.Trimesh(vertices, sphere.faces, process=False)


@pytest.fixture(scope="module")
def blob_folder(tmp_path_factory):
    """Six procedural blobs (642 vertices) as OBJ, PLY and OFF files, and a credits file."""
    folder = tmp_path_factory.mktemp("blobs")
    for i in range(6):
        _blob(i).export(folder / f"blob{i}.{('obj', 'ply', 'off')[i % 3]}")
    (folder / "CREDITS.md").write_text("- blobs: made by the test, public domain\n")
    return folder


def test_folder_to_served_bundle_end_to_end(blob_folder, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(build_module.SOLVERS, "exact", (edge_dijkstra, "edge Dijkstra (test)"))
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    out = tmp_path / "bundle"
    argv = ["train", "geodesic", "--meshes", str(blob_folder), "--out", str(out)]
    # a budget this test never reaches: what it checks must not depend on the machine's load
    argv += ["--init", "quadrupeds", "--time-budget", "20", "--config", str(config)]
    argv += ["--vertices", "150,250", "--shapes-per-mesh", "2", "--eval-shapes-per-mesh", "1"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["bundle"] == str(out) and summary["data"]["files"] == {
        "train": 4,
        "val": 1,
        "test": 1,
    }
    assert summary["data"]["shapes"] == {"train": 8, "val": 1, "test": 1}
    assert summary["training"]["steps"] == 30 and summary["training"]["init"] == "quadrupeds"
    means = summary["held_out"]["mean_over_settings"]
    assert set(means) == {
        f"{blob_folder.name} (this bundle)",
        "quadrupeds (init)",
        "heat",
        "kNN Dijkstra (k=10)",
    }
    assert isinstance(summary["held_out"]["beats_reference"], bool)

    bundle = load_bundle(out)
    assert bundle.content_hash == summary["content_hash"] and bundle.category == "quadruped"
    held_out = bundle.manifest["metrics"]["held_out"]
    assert held_out["reference"] == "quadrupeds (init)" and len(held_out["settings"]) == 6
    card = (out / "MODEL_CARD.md").read_text()
    assert "## Held-out comparison" in card and "| quadrupeds (init) | heat |" in card
    assert "fine-tuned from `quadrupeds`" in card and "blobs: made by the test" in card
    assert "| all | mean over settings |" in (out / "evaluation.md").read_text()

    npy = tmp_path / "d.npy"
    argv = ["geodesic", str(blob_folder / "blob1.ply"), "--sources", "0,5"]
    assert main([*argv, "--model", str(out), "-o", str(npy)]) == 0
    served = json.loads(capsys.readouterr().out)
    assert served["model"] == bundle.name and served["shape"] == [2, 642]
    assert np.isfinite(np.load(npy)).all()


def test_trainer_stops_at_its_deadline(make_config, monkeypatch):
    clock = iter(range(1000))  # each look at the clock advances it by one
    fake_time = types.SimpleNamespace(monotonic=lambda: next(clock), perf_counter=time.perf_counter)
    monkeypatch.setattr(trainer_module, "time", fake_time)
    config = make_config(train={"epochs": 3, "steps_per_epoch": 30})
    trainer = prepare_run(config).trainer
    # looks: before epoch 1 (0), steps 10 and 20 (1, 2); before epoch 2 (3), step 10 (4),
    # step 20 (5 ≥ deadline): epoch 2 ends after 20 steps, no third epoch.
    state = trainer.fit(deadline=5)
    assert state.stopped_by_budget and not state.stopped_early
    assert (state.epoch, state.step) == (2, 50) and len(state.history) == 2
    assert (config.run_dir / "checkpoints" / "last.safetensors").exists()
    # a deadline already passed trains nothing
    again = prepare_run(make_config("late", train={"epochs": 3, "steps_per_epoch": 30})).trainer
    state = again.fit(deadline=-1)
    assert state.stopped_by_budget and state.epoch == 0 and state.step == 0


def test_unbudgeted_fit_runs_every_epoch(make_config):
    state = prepare_run(make_config()).trainer.fit()
    assert state.epoch == 2 and not state.stopped_by_budget


def test_data_budget_spares_evaluation_shapes_and_the_first_training_shard():
    class Inner:
        category, version = "folder", "v1"

        def generate_mesh(self, family, seed):
            return family, seed

    factory = BudgetedFactory(Inner(), deadline=time.time() - 1, always=8)
    assert (factory.category, factory.version) == ("folder", "v1")
    assert factory.generate_mesh("a", 7) == ("a", 7)  # first shard of train
    assert factory.generate_mesh("a", 1_000_003) == ("a", 1_000_003)  # val
    assert factory.generate_mesh("a", 2_000_100) == ("a", 2_000_100)  # test
    with pytest.raises(DataBudgetReached):
        factory.generate_mesh("a", 8)
    later = BudgetedFactory(Inner(), deadline=time.time() + 3600, always=8)
    assert later.generate_mesh("a", 500) == ("a", 500)


def test_generated_configs_and_schedule(tmp_path):
    common = dict(n_train_shapes=100, name="n", category="c")
    tune = folder_config("d", tmp_path, fine_tune=True, budgeted=True, **common)
    assert (tune.train.lr, tune.train.eta_min, tune.train.patience) == (1e-3, 1e-5, 0)
    scratch = folder_config("d", tmp_path, fine_tune=False, **common)
    assert (scratch.train.lr, scratch.train.patience, scratch.basis.n_components) == (
        1e-2,
        4,
        100,
    )
    user = folder_config(
        "d",
        tmp_path,
        fine_tune=True,
        overrides={"train": {"lr": 5e-4}, "data": {"dataset": "elsewhere"}},
        **common,
    )
    assert user.train.lr == 5e-4 and user.data.dataset == "d"  # the command's data wins
    assert user.run_dir == tmp_path
    planned = plan_schedule(tune, seconds=100.0, steps_per_second=20.0)
    total = planned.train.epochs * planned.train.steps_per_epoch
    assert 0.8 * 1700 <= total <= 1.2 * 1700 and 8 <= planned.train.epochs <= 12
    assert plan_schedule(tune, 1.0, 1.0).train.total_steps >= 1


def test_folder_needs_three_mesh_files_and_an_out_directory(tmp_path, capsys):
    _blob(0, 1).export(tmp_path / "a.obj")
    _blob(1, 1).export(tmp_path / "b.ply")
    with pytest.raises(InputError, match="at least 3"):
        check_folder(tmp_path)
    assert main(["train", "geodesic", "--meshes", str(tmp_path)]) == 2
    assert "--meshes needs --out" in capsys.readouterr().err
    out = str(tmp_path / "out")
    assert main(["train", "geodesic", "--meshes", str(tmp_path), "--out", out]) == 2
    assert "at least 3" in capsys.readouterr().err
    argv = ["train", "geodesic", "--meshes", str(tmp_path), "--out", out, "--vertices", "²,3"]
    assert main(argv) == 2  # str.isdigit accepts "²", int does not
    assert "--vertices must be MIN,MAX" in capsys.readouterr().err


def test_matching_from_a_folder_checks_the_topology(tmp_path, capsys):
    shared = tmp_path / "shared"
    shared.mkdir()
    for i in range(3):
        _blob(i, 1).export(shared / f"s{i}.ply")
    files, n_vertices, faces = shared_topology(shared)
    assert len(files) == 3 and n_vertices == 42 and faces.shape == (80, 3)
    assert main(["train", "matching", "--meshes", str(shared)]) == 2
    assert "--meshes needs --out" in capsys.readouterr().err

    mixed = tmp_path / "mixed"
    mixed.mkdir()
    _blob(0, 1).export(mixed / "a.ply")
    _blob(1, 1).export(mixed / "b.ply")
    _blob(2, 2).export(mixed / "c.ply")
    with pytest.raises(InputError, match=r"c\.ply and a\.ply differ \(162 vertices against 42\)"):
        shared_topology(mixed)
    out = str(tmp_path / "out")
    assert main(["train", "matching", "--meshes", str(mixed), "--out", out]) == 2
    err = capsys.readouterr().err
    assert "share one topology" in err and "c.ply and a.ply differ" in err
    blob = _blob(1, 1)
    reordered = trimesh.Trimesh(blob.vertices, blob.faces[:, [1, 2, 0]], process=False)
    reordered.export(mixed / "c.ply")
    with pytest.raises(InputError, match="face 0 is"):
        shared_topology(mixed)


@pytest.mark.parametrize(("flag", "poses"), [((), False), (("--poses",), True)])
def test_poses_is_opt_in(tmp_path, monkeypatch, flag, poses):
    from litege_core.train import from_meshes

    seen = []
    monkeypatch.setattr(from_meshes, "train_from_meshes", lambda options: seen.append(options))
    argv = ["train", "geodesic", "--meshes", str(tmp_path), "--out", str(tmp_path / "b")]
    assert main([*argv, *flag]) == 0
    assert seen[0].poses is poses


def test_one_rig_with_poses_trains_on_its_poses_and_holds_out_others(
    tmp_path, monkeypatch, capsys, rigged_gltf
):
    monkeypatch.setitem(build_module.SOLVERS, "exact", (edge_dijkstra, "edge Dijkstra (test)"))
    folder = tmp_path / "rig"
    folder.mkdir()
    rigged_gltf(folder / "capsule.gltf")
    with pytest.raises(InputError, match="or --poses"):
        check_folder(folder)
    assert check_folder(folder, poses=True) == ("capsule.gltf",)
    static = tmp_path / "static"
    static.mkdir()
    _blob(0, 1).export(static / "a.obj")
    argv = ["train", "geodesic", "--meshes", str(static), "--out", str(tmp_path / "x"), "--poses"]
    assert main(argv) == 2
    assert "every file must be a rigged, animated glTF" in capsys.readouterr().err
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    out = tmp_path / "bundle"
    argv = ["train", "geodesic", "--meshes", str(folder), "--out", str(out), "--poses"]
    argv += ["--init", "quadrupeds", "--time-budget", "20", "--config", str(config)]
    argv += ["--vertices", "150,250", "--shapes-per-mesh", "4", "--eval-shapes-per-mesh", "2"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["data"]["files"] == {"train": 1, "val": 1, "test": 1}
    assert summary["data"]["held_out"] == "held-out test poses"
    assert summary["data"]["shapes"] == {"train": 4, "val": 2, "test": 2}
    assert (out / "evaluation.md").read_text().startswith("Held-out test poses of")


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"shapes_per_mesh": 0}, "at least one shape"),
        ({"eval_shapes_per_mesh": 0}, "at least one shape"),
    ],
)
def test_zero_shapes_per_file_are_refused_not_defaulted(given, message, tmp_path):
    from litege_core.train.from_meshes import FolderTrainOptions
    from litege_core.train.matching_from_meshes import MatchingFolderOptions

    with pytest.raises(InputError, match=message):
        FolderTrainOptions(meshes=tmp_path, out=tmp_path / "b", **given)
    with pytest.raises(InputError):
        MatchingFolderOptions(meshes=tmp_path, out=tmp_path / "b", **given)
    assert FolderTrainOptions(meshes=tmp_path, out=tmp_path / "b").shapes_per_mesh is None
