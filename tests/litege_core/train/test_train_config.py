from pathlib import Path

import pytest

from litege_core.errors import InputError
from litege_core.train.config import TrainConfig, load_config

CONFIGS = Path(__file__).resolve().parents[3] / "configs"

MINIMAL = """
[data]
dataset = "data/toy"

[train]
epochs = 3
lr = 1e-2
eta_min = 1e-4
device = "cpu"
"""


def test_minimal_config_uses_defaults(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(MINIMAL)
    config = load_config(path)
    assert config.data.dataset == "data/toy" and config.train.epochs == 3
    assert config.basis.n_components == 240 and config.network.width == 200
    assert config.train.pairs_per_step == 16 * 12 * 16
    assert config.train.total_steps == 3 * config.train.steps_per_epoch
    assert str(config.resolve_device()) == "cpu"
    assert TrainConfig.from_dict(config.to_dict()) == config
    assert config.replace(train={"epochs": 5}).train.epochs == 5
    assert config.content_hash() != config.replace(train={"epochs": 5}).content_hash()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (MINIMAL + "\nbogus = 1\n", "unknown keys in [train]"),
        (MINIMAL + "\n[extra]\nx = 1\n", "unknown config tables"),
        ('[data]\ndataset = "d"\n[train]\nepochs = "ten"\n', "train.epochs must be a int"),
        ('[data]\ndataset = "d"\n[train]\nlr = true\n', "train.lr must be a float"),
        ('[data]\ndataset = "d"\n[train]\nbatch_views = 1\n', "batch_views"),
        ('[data]\ndataset = "d"\n[network]\noutput = "relu"\n', "network.output"),
        ('[data]\ndataset = "d"\n[augment]\ncut_max = 1.5\n', "cut_max"),
        ("[train]\nepochs = 2\n", "[data]"),
        ("[data\n", "not valid TOML"),
    ],
)
def test_bad_configs_raise_input_error(tmp_path, text, message):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_config(path)
    assert message in str(info.value)


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_config(tmp_path / "nope.toml")


def test_integers_are_accepted_for_floats():
    config = TrainConfig.from_dict({"data": {"dataset": "d"}, "train": {"lr": 1, "eta_min": 1}})
    assert isinstance(config.train.lr, float)


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIGS.glob("geodesic-*.toml")))
def test_repository_configs_parse(name):
    config = load_config(CONFIGS / f"{name}.toml")
    assert config.output.name
