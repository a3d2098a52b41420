"""tools/loss_probe.py: held-out samples drawn as the config draws them (another seed), and a paired comparison
that finds identical weights identical and per-sample terms equal to the loss computed directly."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from d4rt.model import D4RT
from d4rt.training.config import TrainConfig
from d4rt.training.losses import d4rt_loss

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "src" / "d4rt" / "assets" / "d4rt-tiny"
spec = importlib.util.spec_from_file_location("loss_probe", ROOT / "tools" / "loss_probe.py")
loss_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(loss_probe)


@pytest.fixture
def config_path(tmp_path: Path) -> Path:
    config = yaml.safe_load((ROOT / "configs" / "tiny-cpu.yaml").read_text())
    config["data"]["dataset"].update(render_pixels=1024, seed=3, frame_choices=[8, 12])
    config["loss"] = {"weight_pose": 0.5}
    config["model"]["overrides"] = {"relative_pose_head": True}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_samples_come_from_the_held_out_seed_with_the_asked_queries(config_path):
    config = TrainConfig.load(config_path)
    first = loss_probe.held_out_samples(config, 2, 40)
    again = loss_probe.held_out_samples(config, 2, 40)
    assert [s["queries"].shape[0] for s in first] == [40, 40]
    for a, b in zip(first, again):  # deterministic
        assert all(torch.equal(a[k], b[k]) for k in a)
    training = loss_probe.build_dataset(config.data.dataset)[0]  # the training stream's sample 0 differs
    assert not torch.equal(training["video"][:1], first[0]["video"][:1])


def test_identical_weights_compare_equal_and_terms_are_the_loss(config_path, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(SHIPPED, copy)
    out = tmp_path / "probe.json"
    loss_probe.main([str(SHIPPED), str(copy), "--config", str(config_path), "--samples", "3", "--queries", "48",
                     "--out", str(out)])
    result = json.loads(out.read_text())
    assert result["seed"] == loss_probe.HELD_OUT_SEED and result["reference"] == str(SHIPPED)
    paired = result["paired_against_reference"][str(copy)]["3d"]
    assert paired["difference"] == 0.0 and paired["low"] == 0.0 and paired["high"] == 0.0
    assert paired["new_better_on"] == 0 and paired["sequences"] == 3
    assert "pose_rotation" in result["models"][str(SHIPPED)]["mean"]  # the config's pose weight is kept
    assert result["paired_against_reference"][str(copy)]["2d_slope"]["difference"] == 0.0
    # The per-sample L3D is d4rt_loss's on the same sample.
    config = TrainConfig.load(config_path)
    sample = loss_probe.held_out_samples(config, 1, 48)[0]
    batch = {k: v[None] for k, v in sample.items()}
    model = D4RT.from_pretrained(SHIPPED).eval()
    with torch.no_grad():
        expected = float(d4rt_loss(model(batch["video"], batch["queries"], batch["aspect_ratio"]), batch,
                                   config.loss)[1]["3d"])
    values = result["models"][str(SHIPPED)]["samples"]["3d"]
    assert values[0] == pytest.approx(expected, rel=1e-5)
    assert result["models"][str(SHIPPED)]["mean"]["3d"] == pytest.approx(np.mean(values))
    assert "| reference |" in capsys.readouterr().out


def test_a_reference_from_an_earlier_probe_pairs_as_its_weights_would(config_path, tmp_path, capsys):
    """--reference-from: the earlier probe's reference figures stand in for its weights (a run folder gone); a config
    with another loss pairs only the loss-free terms; one drawing other samples is refused in one line."""
    earlier = tmp_path / "earlier.json"
    loss_probe.main([str(SHIPPED), "--config", str(config_path), "--samples", "3", "--queries", "48",
                     "--out", str(earlier)])
    copy = tmp_path / "copy"
    shutil.copytree(SHIPPED, copy)
    out = tmp_path / "later.json"
    loss_probe.main([str(copy), "--config", str(config_path), "--samples", "3", "--queries", "48", "--out", str(out),
                     "--reference-from", str(earlier)])
    result = json.loads(out.read_text())
    assert result["reference"] == str(SHIPPED) and result["reference_from"] == str(earlier)
    paired = result["paired_against_reference"][str(copy)]
    assert paired["3d"]["difference"] == 0.0 and "total" in paired
    other_loss = yaml.safe_load(config_path.read_text())
    other_loss["loss"]["weight_aligned_depth"] = 1.0
    other_loss_path = tmp_path / "other-loss.yaml"
    other_loss_path.write_text(yaml.safe_dump(other_loss))
    loss_probe.main([str(copy), "--config", str(other_loss_path), "--samples", "3", "--queries", "48",
                     "--out", str(out), "--reference-from", str(earlier)])
    paired = json.loads(out.read_text())["paired_against_reference"][str(copy)]
    assert paired["3d"]["difference"] == 0.0 and set(paired) <= set(loss_probe.LOSS_FREE_TERMS)
    other_data = yaml.safe_load(config_path.read_text())
    other_data["data"]["dataset"]["frame_choices"] = [8]
    other_data_path = tmp_path / "other-data.yaml"
    other_data_path.write_text(yaml.safe_dump(other_data))
    capsys.readouterr()
    with pytest.raises(SystemExit):
        loss_probe.main([str(copy), "--config", str(other_data_path), "--samples", "3", "--queries", "48",
                         "--out", str(out), "--reference-from", str(earlier)])
    assert "draws other samples" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        loss_probe.main([str(copy), "--config", str(config_path), "--samples", "2", "--queries", "48",
                         "--out", str(out), "--reference-from", str(earlier)])
    assert "drew (seed, samples, queries)" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # the reference's own weights probed again would overwrite its kept figures
        loss_probe.main([str(SHIPPED), "--config", str(config_path), "--samples", "3", "--queries", "48",
                         "--out", str(out), "--reference-from", str(earlier)])
    assert "is also a checkpoint to probe" in capsys.readouterr().err


def test_motion_terms_measure_how_far_pixels_move():
    # Four queries (u, v, t_src, t_tgt, t_cam): two moved inside the image, one moved outside it, one in its own frame.
    queries = torch.tensor([[0.2, 0.2, 0, 3, 3], [0.5, 0.5, 1, 0, 0], [0.9, 0.9, 0, 2, 2], [0.4, 0.4, 2, 2, 2]])
    target = torch.tensor([[0.3, 0.2], [0.5, 0.9], [1.3, 0.9], [0.4, 0.4]])
    sample = {"queries": queries, "uv": target, "uv_valid": torch.ones(4, dtype=torch.bool),
              "valid": torch.ones(4, dtype=torch.bool)}
    exact = loss_probe.motion_terms(target, sample)
    assert exact["2d_moved"] == 0.0 and exact["2d_slope"] == pytest.approx(1.0)
    assert exact["2d_still"] == pytest.approx(0.1)  # the median of 0.1 and 0.4 (torch's lower median)
    still = loss_probe.motion_terms(queries[:, :2], sample)
    assert still["2d_moved"] == pytest.approx(exact["2d_still"]) and still["2d_slope"] == 0.0
    half = loss_probe.motion_terms((queries[:, :2] + target) / 2, sample)
    assert half["2d_slope"] == pytest.approx(0.5) and half["2d_moved"] == pytest.approx(0.05)
    sample["valid"] = torch.tensor([False, False, True, True])  # nothing moved inside the image is left
    assert all(np.isnan(v) for v in loss_probe.motion_terms(target, sample).values())


def test_query_kind_terms_split_the_l3d_by_query_kind(config_path):
    sample = loss_probe.held_out_samples(TrainConfig.load(config_path), 1, 400)[0]
    exact = loss_probe.query_kind_terms(sample["points"], sample)  # the true points: zero error of every kind
    assert all(v == 0.0 or np.isnan(v) for v in exact.values()) and not np.isnan(exact["3d_depth"])
    torch.manual_seed(0)
    noisy = sample["points"] * (1 + 0.2 * torch.rand(len(sample["points"]), 1))
    terms = loss_probe.query_kind_terms(noisy, sample)
    # The kinds split the valid queries, so their means weighted by their counts give the sample's L3D, and so do
    # the moving and static queries.
    valid = sample["valid"].bool()
    s, t, c = sample["queries"][:, 2], sample["queries"][:, 3], sample["queries"][:, 4]
    per_query = loss_probe.point_loss(noisy[None], sample["points"][None], valid[None])[0]
    counts = {name: int((kind(s, t, c) & valid).sum()) for name, kind in loss_probe.QUERY_KINDS.items()}
    assert sum(counts.values()) == int(valid.sum()) and counts["3d_depth"] > 0 and counts["3d_track"] > 0
    pooled = sum(terms[name] * n for name, n in counts.items() if n) / int(valid.sum())
    assert pooled == pytest.approx(float(per_query[valid].mean()), rel=1e-5)
    moving = int(((sample["motion"].abs().sum(-1) > 0) & valid).sum())
    split = (terms["3d_moving"] * moving + terms["3d_static"] * (int(valid.sum()) - moving)) / int(valid.sum())
    assert split == pytest.approx(pooled, rel=1e-5) and 0 < moving < int(valid.sum())


def test_a_config_with_track_clips_is_refused(tmp_path, capsys):
    config = yaml.safe_load((ROOT / "configs" / "tiny-cpu.yaml").read_text())
    config["data"]["tracks"] = {"directory": str(tmp_path)}
    path = tmp_path / "tracks.yaml"
    path.write_text(yaml.safe_dump(config))
    with pytest.raises(SystemExit):
        loss_probe.main([str(SHIPPED), "--config", str(path), "--out", str(tmp_path / "x.json")])
    assert "data.tracks" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a checkpoint that is not there: one line, before anything is rendered
        loss_probe.main([str(tmp_path / "missing"), "--config", str(ROOT / "configs" / "tiny-cpu.yaml"),
                         "--out", str(tmp_path / "x.json")])
    assert "missing" in capsys.readouterr().err


def test_set_overrides_the_config_and_is_checked(config_path, tmp_path, capsys):
    out = tmp_path / "probe.json"
    loss_probe.main([str(SHIPPED), "--config", str(config_path), "--samples", "2", "--queries", "32", "--out",
                     str(out), "--set", "loss.weight_correspondence=0.2"])
    result = json.loads(out.read_text())
    assert result["overrides"] == ["loss.weight_correspondence=0.2"]
    assert result["models"][str(SHIPPED)]["mean"]["correspondence"] > 0  # the term the override turned on
    with pytest.raises(SystemExit):  # a block the decoder does not have: named, before anything is rendered
        loss_probe.main([str(SHIPPED), "--config", str(config_path), "--out", str(out), "--set",
                         "loss.weight_correspondence=0.2", "--set", "loss.correspondence_block=9"])
    assert "correspondence_block must be below" in capsys.readouterr().err
