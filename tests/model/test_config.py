import pytest

from d4rt.config import D4RTConfig
from d4rt.errors import UserError


@pytest.mark.parametrize("name", D4RTConfig.preset_names())
def test_every_preset_round_trips_through_json(name, tmp_path):
    config = D4RTConfig.preset(name)
    assert D4RTConfig.from_json(config.to_json()) == config
    config.save(tmp_path / "config.json")
    assert D4RTConfig.load(tmp_path / "config.json") == config


def test_presets_cover_the_paper_sizes():
    assert D4RTConfig.preset_names() == ["tiny", "small", "base", "large", "huge", "giant"]
    giant = D4RTConfig.preset("giant")
    # The numbers the paper (and the issue) fix for the main model.
    assert (giant.encoder_dim, giant.encoder_depth, giant.encoder_heads, giant.encoder_mlp_dim) == (1408, 40, 16, 6144)
    assert (giant.tubelet_frames, giant.patch_size, giant.image_size, giant.max_frames) == (2, 16, 256, 48)
    assert giant.decoder_depth == 8
    assert giant.rgb_patch_size == 9 and giant.rgb_patch_source == "encoder"
    # 48 frames at 256 px in 2x16x16 tubelets: 24 * 16 * 16 video tokens, plus the aspect-ratio token.
    assert giant.num_scene_tokens(48) == 24 * 16 * 16 + 1
    for name in ("base", "large", "huge"):
        config = D4RTConfig.preset(name)
        assert (config.tubelet_frames, config.patch_size, config.image_size) == (2, 16, 256)


def test_overrides_and_replace():
    config = D4RTConfig.preset("tiny", rgb_patch_size=0, rgb_patch_source="original")
    assert config.rgb_patch_size == 0 and config.name == "tiny"
    assert config.replace(decoder_depth=1).decoder_depth == 1


def test_default_fourier_max_is_the_encoder_nyquist_frequency():
    config = D4RTConfig.preset("tiny")
    assert config.fourier_max == config.image_size / 2
    assert config.replace(fourier_max_frequency=10.0).fourier_max == 10.0


@pytest.mark.parametrize("overrides, message", [
    ({"encoder_dim": 100, "encoder_heads": 3}, "encoder_dim"),
    ({"image_size": 60}, "patch_size"),
    ({"rgb_patch_source": "elsewhere"}, "rgb_patch_source"),
    ({"rgb_patch_size": -1}, "rgb_patch_size"),
    ({"max_frames": 0}, "max_frames"),
    ({"confidence_activation": "relu"}, "confidence_activation"),
    ({"no_such_field": 1}, "no_such_field"),
    ({"global_attention_every": 7}, "no global-attention block"),
    ({"pixel_mean": "abc"}, "pixel_mean must be 3 numbers"),
    ({"pixel_std": 0.2}, "pixel_std must be 3 numbers"),
    ({"pixel_std": (0.2, 0.2, 0.0)}, "pixel_std must be positive"),
    ({"rgb_patch_size": True}, "rgb_patch_size"),
    ({"fourier_max_frequency": True}, "fourier_max_frequency"),
    ({"init_std": float("nan")}, "init_std"),
    ({"tubelet_stride": 3}, "tubelet_stride must be null or an integer in 1-2"),
    ({"tubelet_stride": 0}, "tubelet_stride"),
    ({"tubelet_stride": 1, "dense_depth_head": True}, "tubelets that do not overlap"),
])
def test_bad_configs_raise_user_errors_naming_the_field(overrides, message):
    with pytest.raises(UserError, match=message):
        D4RTConfig.preset("tiny", **overrides)


def test_unknown_preset_and_bad_json():
    with pytest.raises(UserError, match="unknown preset"):
        D4RTConfig.preset("enormous")
    with pytest.raises(UserError, match="not valid JSON"):
        D4RTConfig.from_json("{")
    with pytest.raises(UserError, match="unknown D4RT config field"):
        D4RTConfig.from_json('{"encoder_width": 3}')
    with pytest.raises(UserError, match="name must be a string"):
        D4RTConfig.from_json('{"name": 5}')
