"""tools/average_weights.py: the weighted average of two checkpoints is what it says, loads strictly, and
checkpoints of different architectures are refused."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "average_weights.py"
spec = importlib.util.spec_from_file_location("average_weights", SCRIPT)
average_weights = importlib.util.module_from_spec(spec)
spec.loader.exec_module(average_weights)


def test_the_average_is_weighted_and_loads(tmp_path):
    config = D4RTConfig.preset("tiny")
    torch.manual_seed(0)
    a = D4RT(config).save_pretrained(tmp_path / "a")
    torch.manual_seed(1)
    b = D4RT(config).save_pretrained(tmp_path / "b")
    tensors, config_text = average_weights.average([a, b], [1.0, 3.0])
    first, second = D4RT.from_pretrained(a).state_dict(), D4RT.from_pretrained(b).state_dict()
    for key, value in tensors.items():
        torch.testing.assert_close(value, 0.25 * first[key] + 0.75 * second[key], rtol=1e-6, atol=1e-7)
    out = tmp_path / "soup"
    out.mkdir()
    from safetensors.torch import save_file

    save_file(tensors, str(out / "model.safetensors"))
    (out / "config.json").write_text(config_text)
    D4RT.from_pretrained(out)  # strict load

    other = D4RT(D4RTConfig.preset("tiny", decoder_depth=2)).save_pretrained(tmp_path / "c")
    with pytest.raises(UserError, match="different configs"):
        average_weights.average([a, other], [0.5, 0.5])
    with pytest.raises(UserError, match="positive"):
        average_weights.average([a, b], [1.0, 0.0])


def assert_part_whole_and_rest_weighted(tensors, start, tuned, part: str, start_weight: float) -> None:
    """The average ``tensors`` of ``start`` (without ``part``) and ``tuned`` (with it) holds the part whole from
    ``tuned`` and every shared tensor weighted ``start_weight`` : ``1 - start_weight``."""
    first, second = D4RT.from_pretrained(start).state_dict(), D4RT.from_pretrained(tuned).state_dict()
    part_keys = [k for k in second if k.startswith(average_weights.ADDABLE_PARTS[part])]
    assert part_keys and set(tensors) == set(second)
    for key, value in tensors.items():
        expected = second[key] if key in part_keys else start_weight * first[key] + (1 - start_weight) * second[key]
        torch.testing.assert_close(value, expected, rtol=1e-6, atol=1e-7)


def test_a_model_that_added_the_pose_head_averages_with_its_start(tmp_path):
    """The trainer may add the relative-pose head to a headless start (init_from): the average of the two has
    the head, taken whole from the checkpoint that has it, and every shared tensor weighted."""
    torch.manual_seed(0)
    start = D4RT(D4RTConfig.preset("tiny")).save_pretrained(tmp_path / "start")
    headed_config = D4RTConfig.preset("tiny", relative_pose_head=True, pose_pairs="adjacent")
    torch.manual_seed(1)
    tuned = D4RT(headed_config).save_pretrained(tmp_path / "tuned")
    tensors, config_text = average_weights.average([start, tuned], [3.0, 1.0])
    assert_part_whole_and_rest_weighted(tensors, start, tuned, "relative_pose_head", 0.75)
    out = tmp_path / "soup"
    out.mkdir()
    from safetensors.torch import save_file

    save_file(tensors, str(out / "model.safetensors"))
    (out / "config.json").write_text(config_text)
    soup = D4RT.from_pretrained(out)  # strict load
    assert soup.config == headed_config

    torch.manual_seed(2)
    other_pairs = D4RT(headed_config.replace(pose_pairs="first")).save_pretrained(tmp_path / "other")
    with pytest.raises(UserError, match="different pose_pairs"):
        average_weights.average([start, tuned, other_pairs], [1.0, 1.0, 1.0])
    # Named for the average, the pairing (an inference choice) no longer has to be shared.
    named, named_config = average_weights.average([tuned, other_pairs], [1.0, 1.0], pose_pairs="graph")
    assert D4RTConfig.from_json(named_config) == headed_config.replace(pose_pairs="graph")
    deeper = D4RT(D4RTConfig.preset("tiny", decoder_depth=2, relative_pose_head=True)).save_pretrained(tmp_path / "d")
    with pytest.raises(UserError, match="different configs"):
        average_weights.average([start, deeper], [0.5, 0.5])


def test_a_model_that_added_the_dense_depth_head_averages_with_its_start(tmp_path):
    """As the pose head: a start like the shipped model (pose head, adjacent pairs) averaged with a run that added the
    dense depth head (stage 67) has the head whole from that run and the run's config."""
    start_config = D4RTConfig.preset("tiny", relative_pose_head=True, pose_pairs="adjacent")
    torch.manual_seed(0)
    start = D4RT(start_config).save_pretrained(tmp_path / "start")
    torch.manual_seed(1)
    tuned = D4RT(start_config.replace(dense_depth_head=True)).save_pretrained(tmp_path / "tuned")
    tensors, config_text = average_weights.average([start, tuned], [1.0, 1.0])
    assert_part_whole_and_rest_weighted(tensors, start, tuned, "dense_depth_head", 0.5)
    assert D4RTConfig.from_json(config_text) == start_config.replace(dense_depth_head=True)


def test_a_run_with_another_motion_threshold_averages_once_the_average_names_one(tmp_path):
    import json
    import re

    from d4rt.config import MOTION_THRESHOLD

    torch.manual_seed(0)
    shipped = D4RT(D4RTConfig.preset("tiny", motion_threshold=0.2)).save_pretrained(tmp_path / "shipped")
    torch.manual_seed(1)
    older = D4RT(D4RTConfig.preset("tiny")).save_pretrained(tmp_path / "older")  # the default threshold
    named = re.escape(str(sorted([MOTION_THRESHOLD, 0.2])))  # the default and the shipped calibration, named
    with pytest.raises(UserError, match=rf"different motion_threshold values {named}: .*--motion-threshold"):
        average_weights.average([shipped, older], [0.5, 0.5])
    tensors, config_text = average_weights.average([shipped, older], [0.5, 0.5], motion_threshold=0.2)
    assert json.loads(config_text)["motion_threshold"] == 0.2
    first, second = D4RT.from_pretrained(shipped).state_dict(), D4RT.from_pretrained(older).state_dict()
    for key, value in tensors.items():  # the weights are averaged as ever
        torch.testing.assert_close(value, 0.5 * first[key] + 0.5 * second[key], rtol=1e-6, atol=1e-7)
