"""T-Net training configuration: the shipped configs, validation errors, config files."""

from pathlib import Path

import pytest

from litege_core.errors import InputError
from litege_core.train.tnet import TNetTrainConfig, load_tnet_config
from tests.litege_core.train.tnet.conftest import REPO


def test_shipped_config_loads_and_round_trips() -> None:
    config = load_tnet_config(REPO / "configs" / "tnet-quadrupeds.toml")
    assert config.data.category == "quadruped"
    assert config.network.conv_widths == (64, 128, 256) and config.network.prealign == "pca"
    assert config.train.lr == 1e-3 and config.train.eta_min == 1e-5
    assert config.report.rotation_seed == 20 and config.report.failure_threshold == 0.66
    again = TNetTrainConfig.from_dict(config.to_dict())
    assert again == config and again.content_hash() == config.content_hash()
    assert config.replace(train={"steps": 5}).train.steps == 5


@pytest.mark.parametrize(
    "data",
    [
        {"nope": {}},
        {"train": {"stepz": 3}},
        {"train": {"steps": "10"}},
        {"train": {"steps": 0}},
        {"train": {"batch_size": 1}},
        {"train": {"lr": 1e-5, "eta_min": 1e-3}},
        {"train": {"val_every": True}},
        {"augment": {"min_points": 600, "max_points": 500}},
        {"augment": {"broken_probability": 1.5}},
        {"augment": {"scale_min": 0.0}},
        {"augment": {"axis_scale": 1.0}},
        {"network": {"conv_widths": [64, "128"]}},
        {"network": {"conv_widths": []}},
        {"network": {"fc_widths": [0]}},
        {"network": {"conv_widths": 64}},
        {"network": {"prealign": "svd"}},
        {"data": {"n_train": 0}},
        {"data": {"n_extra_train": 4}},
        {"data": {"extra_category": "folder", "n_extra_train": 4}},
        {"data": {"extra_category": "makehuman", "n_extra_val": -1}},
        {"data": {"extra_category": "makehuman", "n_extra_train": 4, "extra_bend": 0.5}},
        {"data": {"extra_category": "rigged", "n_extra_train": 4, "extra_bend": 1.5}},
        {"data": {"steep_share": -0.1}},
        {"data": {"steep_share": 1.5}},
        {"data": {"category": "biped", "steep_share": 0.3}},
        {"report": {"broken_fraction": 1.0}},
        {"output": {"dir": ""}},
        {"data": []},
    ],
)
def test_config_validation_errors(data: dict) -> None:
    with pytest.raises(InputError):
        TNetTrainConfig.from_dict(data)


def test_config_file_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        load_tnet_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[train\nsteps = 3\n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_tnet_config(bad)
    with pytest.raises(InputError):
        TNetTrainConfig().replace(nope={"x": 1})
