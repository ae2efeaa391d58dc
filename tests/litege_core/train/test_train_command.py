import argparse
import json

import pytest

from litege_core.cli.train import add_train_parser
from litege_core.errors import ArtifactError, InputError
from litege_core.learned import load_bundle
from litege_core.train.pipeline import train_geodesic


def _toml(data: dict) -> str:
    lines = []
    for table, values in data.items():
        lines.append(f"[{table}]")
        for key, value in values.items():
            lines.append(f"{key} = {json.dumps(value)}")  # str/int/float/bool are valid TOML
    return "\n".join(lines) + "\n"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="litege")
    add_train_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def test_parser_registers_train_geodesic():
    args = _parser().parse_args(
        ["train", "geodesic", "--config", "c.toml", "--resume", "r", "--out", "o"]
    )
    assert (args.config, args.resume, args.out) == ("c.toml", "r", "o")
    assert callable(args.handler)
    with pytest.raises(SystemExit):
        _parser().parse_args(["train", "geodesic"])  # --config is required


def test_command_trains_and_exports(make_config, tmp_path, capsys):
    config = make_config("from-file", train={"epochs": 1, "steps_per_epoch": 3})
    path = tmp_path / "toy.toml"
    path.write_text(_toml(config.to_dict()))
    out = tmp_path / "elsewhere"
    args = _parser().parse_args(["train", "geodesic", "--config", str(path), "--out", str(out)])
    assert args.handler(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["steps"] == 3 and summary["bundle"] == str(out / "bundle")
    bundle = load_bundle(out / "bundle")
    assert bundle.manifest["training"]["config"]["output"]["dir"] == str(out)
    assert not config.run_dir.exists()


def test_resume_from_a_foreign_file_fails_clearly(make_config, tmp_path):
    bogus = tmp_path / "bogus.safetensors"
    bogus.write_bytes(b"not a checkpoint")
    with pytest.raises(ArtifactError, match="cannot read checkpoint"):
        train_geodesic(make_config(), resume=bogus)


def test_a_run_directory_that_cannot_be_made_is_an_input_error(make_config, tmp_path):
    """A run directory under a file is named in an InputError, not an OSError."""
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="cannot create output directory"):
        train_geodesic(make_config("file/run"))


def test_config_run_stops_at_its_time_budget_and_exports_the_best(make_config, tmp_path, capsys):
    config = make_config("budgeted", train={"epochs": 5, "steps_per_epoch": 40})
    path = tmp_path / "toy.toml"
    path.write_text(_toml(config.to_dict()))
    out = tmp_path / "run"
    args = _parser().parse_args(
        ["train", "geodesic", "--config", str(path), "--out", str(out), "--time-budget", "1e-9"]
    )
    assert args.handler(args) == 0
    summary = json.loads(capsys.readouterr().out)
    # the deadline is looked at every BUDGET_CHECK_STEPS steps: a spent budget ends the first
    # epoch there, and no second epoch starts; the run still exports a bundle
    assert summary["steps"] < 40
    bundle = load_bundle(out / "bundle")
    assert bundle.manifest["training"]["steps"] == summary["steps"]


@pytest.mark.parametrize("budget", ["0", "-1", "nan"])
def test_a_time_budget_that_is_not_positive_is_refused(make_config, tmp_path, budget):
    """--time-budget 0, negative or NaN is an InputError before anything is trained."""
    path = tmp_path / "toy.toml"
    path.write_text(_toml(make_config("refused").to_dict()))
    out = tmp_path / "run"
    args = _parser().parse_args(
        ["train", "geodesic", "--config", str(path), "--out", str(out), "--time-budget", budget]
    )
    with pytest.raises(InputError, match="time budget must be a positive number of minutes"):
        args.handler(args)
    assert not out.exists()


def test_config_run_without_a_budget_runs_every_epoch(make_config):
    config = make_config("unbudgeted", train={"epochs": 2, "steps_per_epoch": 3})
    result = train_geodesic(config, time_budget_s=None)
    assert result.state.epoch == 2 and not result.state.stopped_by_budget
    assert result.manifest is not None
