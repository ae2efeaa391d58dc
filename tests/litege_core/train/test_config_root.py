"""The three training configs (geodesic, T-Net, matching) share one root: one strict reader,
round trips, ``replace``, ``content_hash`` and the run directory."""

from __future__ import annotations

from pathlib import Path

import pytest

from litege_core.errors import InputError
from litege_core.train.config import ConfigRoot, TrainConfig, load_config
from litege_core.train.matching import MatchingTrainConfig, load_matching_config
from litege_core.train.tnet import TNetTrainConfig, load_tnet_config

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
SHIPPED = [
    (load_config, "geodesic-quadrupeds.toml"),
    (load_tnet_config, "tnet-quadrupeds.toml"),
    (load_matching_config, "matching-quadrupeds.toml"),
]


@pytest.mark.parametrize(("load", "name"), SHIPPED)
def test_every_config_is_a_config_root_and_round_trips(load, name):
    config = load(CONFIGS / name)
    assert isinstance(config, ConfigRoot)
    again = type(config).from_dict(config.to_dict())
    assert again == config and again.content_hash() == config.content_hash()
    assert type(config).load(CONFIGS / name) == config
    assert config.run_dir == Path(config.output.dir)
    moved = config.replace(output={"dir": "elsewhere"})
    assert isinstance(moved, type(config)) and moved.run_dir == Path("elsewhere")
    assert moved.content_hash() != config.content_hash()
    with pytest.raises(InputError, match="unknown config table"):
        config.replace(nonsense={"x": 1})


@pytest.mark.parametrize("cls", [TrainConfig, TNetTrainConfig, MatchingTrainConfig])
def test_every_config_is_strict_about_tables_and_keys(cls):
    minimal = {"data": {"dataset": "d"}} if cls is TrainConfig else {}
    assert isinstance(cls.from_dict(minimal), cls)
    with pytest.raises(InputError, match="unknown config tables"):
        cls.from_dict({**minimal, "nonsense": {}})
    with pytest.raises(InputError, match="unknown keys in \\[output\\]"):
        cls.from_dict({**minimal, "output": {"nonsense": 1}})
    with pytest.raises(InputError, match="must be a str"):
        cls.from_dict({**minimal, "output": {"dir": 3}})
    with pytest.raises(InputError, match="must be a table"):
        cls.from_dict([])


def test_required_tables_and_cross_table_checks_run_on_every_path():
    with pytest.raises(InputError, match=r"needs a \[data\] table"):
        TrainConfig.from_dict({"train": {"epochs": 1}})
    matching = load_matching_config(CONFIGS / "matching-quadrupeds.toml")
    with pytest.raises(InputError, match="eta_min"):
        matching.replace(train={"eta_min": 1.0, "lr": 0.1})  # check() runs on replace too
