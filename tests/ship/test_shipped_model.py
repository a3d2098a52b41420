"""The model that ships in the package (src/d4rt/assets/d4rt-tiny, MODEL_CARD.md): it loads strictly,
is used by default, and still measures what its model card says.

The regression test re-runs the real ``d4rt eval`` command on a fixed subset of synthetic-dynamic-v1 (the
first SUBSET_CLIPS clips, written once to ``expected-subset.json`` by that same command, see MODEL_CARD.md
"Reproduce") and compares every figure. Tolerance (RTOL, ATOL): the model runs in float32 and its
outputs move by about 1e-6 relative between thread counts and CPU kernels (summation order); the
continuous metrics (AbsRel, ATE, RPE, L1) move by as little, and a threshold metric (delta<1.25, APD3D,
3D-AJ, OA, AUC@30) moves only where a value sits on a threshold: one point of the subset clip flipping
changes APD3D by ~1e-4, delta<1.25 by ~3e-6. 1e-3 allows for a few such flips and nothing more: a change
to the weights, the model or a recipe moves these figures by percent (the half-trained checkpoint of the
same run differs by more than 10% in every one).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import d4rt
from d4rt.cli import main
from d4rt.config import D4RTConfig
from d4rt.model import D4RT
from d4rt.model.weights import bundled_model_dir
from d4rt.training.config import TrainConfig
from subprocess_budget import budget

ROOT = Path(__file__).resolve().parents[2]
EXPECTED = Path(__file__).with_name("expected-subset.json")
CARD_EVAL = ROOT / "docs" / "model-card" / "eval-synthetic-dynamic-v1.json"
SHIP_CONFIG = ROOT / "configs" / "ship-tiny-cpu-stage141-queries-256-soup.yaml"
# The camera pairing the ship judge chose on held-out clips (benchmarks/judge_pairing.py writes it into the shipped
# config.json); the training config names the pairing its run used.
SHIP_POSE_PAIRS = "adjacent"
# The moving-object threshold chosen for these weights on held-out clips (tools/motion_mask_probe.py, best mean F1 of
# thresholds 0.02-0.8 over 8 clips of seeds 7,000,000 + index: docs/outputs.md); written into the shipped config.json.
SHIP_MOTION_THRESHOLD = 0.2
SUBSET_CLIPS = 1
RTOL = ATOL = 1e-3
MAX_BYTES = 30 * 2**20


def d4rt_rows(results: dict) -> dict[str, dict]:
    """Per-sequence metrics of the d4rt method of a ``d4rt eval`` JSON."""
    method = next(m for m in results["methods"] if m["name"] == "d4rt")
    return {row["name"]: row["metrics"] for row in method["sequences"]}


def assert_same_figures(actual: dict[str, dict], expected: dict[str, dict]) -> None:
    assert actual.keys() == expected.keys()
    for name, metrics in expected.items():
        for key, value in metrics.items():
            got = actual[name][key]
            if value is None:
                assert got is None, (name, key, got)
            else:
                assert got == pytest.approx(value, rel=RTOL, abs=ATOL), (name, key, got, value)


def test_bundled_model_loads_strictly_and_is_small():
    directory = bundled_model_dir()
    assert sorted(p.name for p in directory.iterdir()) == ["config.json", "model.safetensors"]
    assert sum(p.stat().st_size for p in directory.iterdir()) < MAX_BYTES
    model = D4RT.from_pretrained()  # strict: every key and shape checked (tests/model/test_weights.py)
    assert not model.training
    # It is the model the shipped config trains: the tiny preset with the config's overrides, at the judge's pairing.
    trained = TrainConfig.load(SHIP_CONFIG).model.build().replace(pose_pairs=SHIP_POSE_PAIRS,
                                                                  motion_threshold=SHIP_MOTION_THRESHOLD)
    assert model.config == trained == D4RTConfig.load(directory / "config.json")
    assert all(np.isfinite(p.detach().numpy()).all() for p in model.parameters())


def test_reconstruct_uses_the_bundled_model_by_default(tmp_path, capsys, room_clip):
    video = tmp_path / "clip.npy"
    np.save(video, room_clip.rgb)
    status = main(["reconstruct", str(video), "-o", str(tmp_path / "out"), "--outputs", "npz"])
    assert status == 0, capsys.readouterr().err
    with np.load(tmp_path / "out" / "reconstruction.npz") as npz:
        assert npz["depth"].shape == room_clip.depth.shape and np.isfinite(npz["depth"]).all()


def test_subset_figures_are_the_model_cards():
    """The expected subset figures are the model card's per-clip rows (both written by d4rt eval)."""
    card = d4rt_rows(json.loads(CARD_EVAL.read_text()))
    expected = d4rt_rows(json.loads(EXPECTED.read_text()))
    assert len(expected) == SUBSET_CLIPS
    assert_same_figures(expected, {name: card[name] for name in expected})


@pytest.mark.slow(seconds=224)
def test_shipped_model_reproduces_its_figures_on_a_subset(tmp_path):
    out = tmp_path / "subset.json"
    env = {**os.environ, "PYTHONPATH": str(Path(d4rt.__file__).parents[1])}
    r = subprocess.run([sys.executable, "-m", "d4rt", "eval", "--benchmark", "synthetic-dynamic-v1",
                        "--checkpoint", str(bundled_model_dir()), "--baseline", "constant-depth",
                        "--limit", str(SUBSET_CLIPS), "--out", str(out)],
                       capture_output=True, text=True, timeout=budget(900), env=env)
    assert r.returncode == 0, r.stderr
    assert_same_figures(d4rt_rows(json.loads(out.read_text())), d4rt_rows(json.loads(EXPECTED.read_text())))


def test_model_card_matches_its_sources():
    """Every measured number in MODEL_CARD.md is generated from docs/model-card/*.json."""
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "model_card.py"), "--check"], capture_output=True,
                       text=True, timeout=budget(120))
    assert r.returncode == 0, r.stderr + r.stdout


def test_derived_and_direct_point_clouds_of_the_model_agree_within_tolerance(room_clip):
    """On the model the depth-derived cloud (the exports' default) and the direct recipe differ by how well
    its depth, its cameras and its direct answers agree: measured 0.115 of the scene's mean radius (median;
    on a 12-frame room clip, where the derived cloud was also the closer of the two to the truth after a
    Sim(3) fit, 0.62 vs 0.68); on this clip 0.21 with stage 101's weights and 0.34 with stage 103's, whose
    derived cloud is still the closer to the truth (median error after a Sim(3) fit 0.39 of the truth's
    radius, the direct 0.48; stage 101's 0.38 and 0.43). The bound leaves room for that and catches a broken
    derivation (which would be off by the scene's size)."""
    from d4rt.io.output_plan import compute_outputs

    rec = D4RT.from_pretrained().reconstruct(room_clip.rgb, progress=False)
    derived = compute_outputs(rec, ["ply"], point_stride=2)
    direct = compute_outputs(rec, ["ply"], point_stride=2, points_from="queries")
    assert np.array_equal(derived.point_pixels, direct.point_pixels)
    radius = np.linalg.norm(direct.points - direct.points.mean(0), axis=1).mean()
    assert np.median(np.linalg.norm(derived.points - direct.points, axis=1)) < 0.5 * radius


@pytest.mark.slow(seconds=100)
def test_bf16_answers_stay_within_stated_tolerance_of_fp32():
    """d4rt reconstruct's default on an AMX / AVX512-BF16 CPU is bf16 autocast: on a synthetic clip with the
    shipped model its depth and cameras stay within the tolerance docs/performance.md states of the
    float32 answers, and are as accurate against the exact ground truth; --dtype fp32 is plain float32.
    Stated: depth and confidence 3e-3, cameras 5e-3 (relative norm; the shipped model chains its cameras from
    adjacent frame pairs; stage 101's weights measured depth 2.0e-3, confidence 1.2e-3, cameras 2.2e-3 here on an
    AVX512-BF16 CPU and 1.8e-3, 1.2e-3, 2.4e-3 on an AMX one; stage 103's 2.4e-3, 1.0e-3, 3.5e-3 on the AMX one;
    the average of stages 103 and 104 3.2e-3, 1.2e-3, 2.9e-3 on the AMX one; stage 107's soup 2.4e-3, 1.1e-3,
    1.5e-3 there; stage 118's soup 2.2e-3, 1.0e-3, 1.9e-3 there), with the same camera ATE against the truth (within
    5%; stage 101's 0.142 and 0.140, stage 103's 0.272 and 0.264, the average's 0.058 and 0.058, the soup's 0.111 and
    0.112, stage 118's 0.262 and 0.263); tracks, whose window hand-off thresholds visibility, 5e-2 (measured 1.4e-3,
    3.2e-3, 1.4e-3 and 2.0e-3). Stage 118's soup with depth at the quarter grid below, emulated bf16 on a 2-core AVX2
    AMD EPYC (2026-12-05): depth 2.1e-3, confidence 1.1e-3, cameras 2.2e-3, tracks 2.7e-3, ATE 0.262 and 0.264,
    AbsRel 0.426 and 0.425 (222 s at 64x80 there, about 100 s at 32x40). Stage 135's weights (0.75 x stage 118's soup
    + 0.25 x stage 135) at the quarter grid on an AMX Intel Xeon (2026-12-06): depth 1.4e-3, confidence 9.7e-4, cameras
    1.2e-3, tracks 2.2e-3, ATE 0.285 and 0.286, AbsRel 0.406 and 0.406 (9 s). Stage 141's weights (0.5 x stage 135's
    + 0.25 x each of stage 141's two legs) at the quarter grid on an AVX512-BF16 AMD EPYC (2026-12-06): depth 1.6e-3,
    confidence 1.0e-3, cameras 2.8e-3, tracks 2.4e-3, ATE 0.321 and 0.320, AbsRel 0.400 and 0.400 (9 s)."""
    import torch

    from d4rt.evaluation.metrics import pose_metrics
    from d4rt.reconstruction import Reconstruction
    from d4rt.synthetic import render_clip

    clip = render_clip(2, 30, 64, 80, environment="room", camera_motion="orbit", num_objects=4)
    model = D4RT.from_pretrained()
    # Depth at a quarter of the pixels: each query is answered on its own, so a quarter of them reads the same
    # per-answer difference at a quarter of the cost (emulated bf16 on an AVX2-only CPU is several times slower
    # than float32). The figures above were measured at 64x80; the truth is the oracle's at the same queries.
    size = (32, 40)
    true_depth = Reconstruction.from_clip(clip).depth(resolution=size).depth

    def answers():
        rec = Reconstruction.from_model(model, clip.rgb, progress=False)  # 2 windows of 24 frames
        depth = rec.depth(resolution=size)
        tracks = rec.tracks([[0, 20, 20], [29, 60, 40], [12, 40, 30]], frame="world")
        return {"depth": depth.depth, "confidence": depth.confidence, "cam_to_world": rec.cameras().cam_to_world,
                "tracks": tracks.points}

    fp32 = answers()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        bf16 = answers()

    def relative(key):
        ok = np.isfinite(fp32[key]) & np.isfinite(bf16[key])
        return np.linalg.norm((bf16[key] - fp32[key])[ok]) / np.linalg.norm(fp32[key][ok])

    assert relative("depth") < 3e-3 and relative("confidence") < 3e-3 and relative("cam_to_world") < 5e-3
    ate = {name: pose_metrics(answer["cam_to_world"], clip.cam_to_world)["ate"] for name, answer in
           (("fp32", fp32), ("bf16", bf16))}
    assert abs(ate["bf16"] - ate["fp32"]) < 0.05 * ate["fp32"], ate
    assert relative("tracks") < 5e-2

    def abs_rel(depth):  # one scale for the clip, as d4rt eval's median alignment
        scale = np.median(true_depth) / np.median(depth)
        return float(np.mean(np.abs(scale * depth - true_depth) / true_depth))

    assert abs(abs_rel(bf16["depth"]) - abs_rel(fp32["depth"])) < 0.01 * abs_rel(fp32["depth"])
