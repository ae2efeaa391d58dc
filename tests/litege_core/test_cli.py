import json
import subprocess
import sys
from pathlib import Path

from litege_core.cli import main
from litege_core.io import save_shape
from litege_core.shape import Shape


def test_info_prints_summary(tmp_path, sphere_mesh, capsys):
    shape = Shape.from_arrays(*sphere_mesh)
    save_shape(shape, tmp_path / "s.obj")
    assert main(["info", str(tmp_path / "s.obj")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["content_hash"] == shape.content_hash
    assert report["n_points"] == shape.n_points and report["kind"] == "mesh"
    assert "rig" not in report  # only glTF files can hold one


def test_info_names_the_clips_a_folder_training_poses(tmp_path, sphere_mesh, rigged_gltf, capsys):
    rigged_gltf(tmp_path / "capsule.gltf")
    assert main(["info", str(tmp_path / "capsule.gltf")]) == 0
    assert json.loads(capsys.readouterr().out)["rig"] == {"clips": ["lift"], "joints": 2}
    save_shape(Shape.from_arrays(*sphere_mesh), tmp_path / "still.glb")
    assert main(["info", str(tmp_path / "still.glb")]) == 0
    assert json.loads(capsys.readouterr().out)["rig"] is None


def test_info_reports_errors_with_code(tmp_path, capsys):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    assert main(["info", str(bad)]) == 2
    assert "[non-finite-coordinates]" in capsys.readouterr().err


def test_console_script_is_installed():
    script = Path(sys.executable).with_name("litege")
    result = subprocess.run([str(script), "--version"], capture_output=True, text=True, check=True)
    assert result.stdout.startswith("litege ")


def test_data_build_refuses_bends_outside_the_rigged_animals(tmp_path, capsys):
    code = main(
        ["data", "build", "--category", "quadruped", "--bend", "0.5", "--out", str(tmp_path)]
    )
    assert code == 2
    assert "rigged animals only" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_data_build_refuses_steep_poses_for_procedural_bipeds(tmp_path, capsys):
    code = main(["data", "build", "--category", "biped", "--steep", "0.3", "--out", str(tmp_path)])
    assert code == 2
    assert "no steep poses" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
