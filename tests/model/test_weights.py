"""save_pretrained / from_pretrained: exact round trip, strict refusal of mismatched checkpoints."""

import json

import pytest
import torch
from safetensors.torch import load_file, save_file

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.encoded_scene import OUTPUT_KEYS
from d4rt.model.weights import CONFIG_NAME, WEIGHTS_NAME


@pytest.fixture
def saved(make_model, tmp_path):
    model = make_model(rgb_patch_size=5)
    # Move every parameter away from its initial value so a fresh init could not pass by accident.
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn_like(p) * 0.01)
    return model, model.save_pretrained(tmp_path / "ckpt")


def test_save_load_round_trip_is_exact(saved, random_video, random_queries):
    model, directory = saved
    assert sorted(p.name for p in directory.iterdir()) == [CONFIG_NAME, WEIGHTS_NAME]
    loaded = D4RT.from_pretrained(directory)
    assert loaded.config == model.config and not loaded.training
    for (name, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    video, queries = random_video(3, 20, 28), random_queries(9, 3)
    a, b = model.encode(video).query(queries), loaded.encode(video).query(queries)
    for key in OUTPUT_KEYS:
        assert torch.equal(a[key], b[key]), key


def test_config_json_is_readable_and_complete(saved):
    model, directory = saved
    data = json.loads((directory / CONFIG_NAME).read_text())
    assert D4RTConfig.from_dict(data) == model.config


def test_checkpoint_for_another_config_is_refused_naming_the_keys(saved):
    _, directory = saved
    config = json.loads((directory / CONFIG_NAME).read_text())
    config["decoder_depth"] = 5  # the weights have 4 decoder blocks
    (directory / CONFIG_NAME).write_text(json.dumps(config))
    with pytest.raises(UserError, match=r"missing keys: decoder\.blocks\.4\.") as err:
        D4RT.from_pretrained(directory)
    assert "\n" not in str(err.value)


def test_wrong_shape_and_unexpected_keys_are_named(saved):
    _, directory = saved
    tensors = load_file(str(directory / WEIGHTS_NAME))
    tensors["encoder.aspect_embed.weight"] = torch.zeros(7, 1)
    tensors["decoder.extra.weight"] = torch.zeros(1)
    del tensors["decoder.heads.heads.uv.bias"]
    save_file(tensors, str(directory / WEIGHTS_NAME))
    with pytest.raises(UserError) as err:
        D4RT.from_pretrained(directory)
    message = str(err.value)
    assert "missing keys: decoder.heads.heads.uv.bias" in message
    assert "unexpected keys: decoder.extra.weight" in message
    assert "shape mismatch: encoder.aspect_embed.weight (7, 1) vs model (192, 1)" in message


def test_load_checked_state_dict_refuses_partial_dicts(make_model):
    model = make_model()
    state = model.state_dict()
    state.pop("encoder.norm.weight")
    with pytest.raises(UserError, match="missing keys: encoder.norm.weight"):
        model.load_checked_state_dict(state)


def test_missing_files_and_bundled_model(tmp_path, monkeypatch):
    with pytest.raises(UserError, match="checkpoint directory not found"):
        D4RT.from_pretrained(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="has no config.json"):
        D4RT.from_pretrained(tmp_path / "empty")
    # An installation without the bundled model (tests/ship checks the one that ships).
    monkeypatch.setattr("d4rt.model.d4rt.bundled_model_dir", lambda: tmp_path / "empty")
    with pytest.raises(UserError, match="no bundled model ships"):
        D4RT.from_pretrained()


def test_from_pretrained_loads_the_bundled_model_when_one_ships(make_model, tmp_path, monkeypatch):
    # The no-argument path reads the package assets directory; point it at a saved model.
    model = make_model()
    model.save_pretrained(tmp_path / "d4rt-tiny")
    monkeypatch.setattr("d4rt.model.d4rt.bundled_model_dir", lambda: tmp_path / "d4rt-tiny")
    loaded = D4RT.from_pretrained()
    assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), loaded.state_dict().values()))


@pytest.mark.parametrize("damage, message", [
    (lambda d: (d / WEIGHTS_NAME).write_bytes((d / WEIGHTS_NAME).read_bytes()[:-100]), "cannot read .*model.safetensors"),
    (lambda d: (d / WEIGHTS_NAME).write_bytes(b"not a safetensors file"), "cannot read .*model.safetensors"),
    (lambda d: (d / WEIGHTS_NAME).unlink(), "has no model.safetensors"),
    (lambda d: (d / CONFIG_NAME).write_bytes(b"\xff\xfe{"), "cannot read config file .*config.json"),
    (lambda d: (d / CONFIG_NAME).write_text("{"), "config.json: config is not valid JSON"),
    (lambda d: (d / CONFIG_NAME).write_text('{"encoder_width": 192}'), "config.json: unknown D4RT config field"),
])
def test_corrupt_or_missing_checkpoint_files_raise_one_line(saved, damage, message):
    _, directory = saved
    damage(directory)
    with pytest.raises(UserError, match=message) as err:
        D4RT.from_pretrained(directory)
    assert "\n" not in str(err.value)
