"""The paper's query sampler and augmentations: statistics, exactness through views, datasets."""

import numpy as np
import pytest
import torch

from d4rt.data import (AugmentConfig, ClipQueryDataset, DatasetConfig, QuerySampler, QuerySamplerConfig,
                       boundary_mask, make_training_sample, photometric_augment, sample_view)
from d4rt.data.sampler import scene_flow
from d4rt.errors import UserError
from d4rt.geometry.camera import project
from d4rt.geometry.view import View
from d4rt.synthetic import Clip


def test_scene_flow_is_zero_on_static_bodies_and_exact_on_moving_ones(room_clip):
    flow = scene_flow(room_clip).double().numpy()
    kinds = room_clip.scene.info["body_motion"]
    static = np.isin(room_clip.object_ids, [k for k, kind in enumerate(kinds) if kind in ("environment", "static")])
    assert np.abs(flow[static]).max() < 1e-5  # float32
    # Exact: the oracle's world-frame displacement from frame 2 to 3 of the same pixels.
    ys, xs = np.nonzero(~static[2])
    q = np.stack([(xs + 0.5) / 64, (ys + 0.5) / 48, np.full(len(xs), 2), np.full(len(xs), 3), np.zeros(len(xs))], 1)
    moved = room_clip.oracle.query(q)["motion"].numpy()  # in camera 0
    world = moved @ room_clip.cam_to_world[0, :3, :3].T
    assert np.abs(world - flow[2, ys, xs]).max() < 1e-5


def test_edge_and_blur_filters_are_exact_on_planes():
    from d4rt.data.augment import _gaussian_blur
    from d4rt.data.sampler import _sobel_magnitude
    ys, xs = torch.meshgrid(torch.arange(20.0, dtype=torch.float64), torch.arange(30.0, dtype=torch.float64),
                            indexing="ij")
    plane = (0.3 * xs - 0.4 * ys)[None, None]  # (1, 1, 20, 30): gradient (0.3, -0.4) per pixel
    magnitude = _sobel_magnitude(torch.cat([plane, 2 * plane], 1))  # two channels in quadrature
    assert torch.allclose(magnitude[0, 1:-1, 1:-1], torch.tensor(0.5 * 5 ** 0.5, dtype=torch.float64), atol=1e-12)
    # Top row: the replicated border halves the vertical difference, (0.3, -0.2).
    assert torch.allclose(magnitude[0, 0, 1:-1], torch.tensor((5 * 0.13) ** 0.5, dtype=torch.float64), atol=1e-12)
    # A symmetric kernel leaves a plane unchanged away from the borders (reach ceil(3 sigma) = 5), and a
    # constant everywhere.
    blurred = _gaussian_blur(plane, 1.6, 1.6)
    assert torch.allclose(blurred[..., 5:-5, 5:-5], plane[..., 5:-5, 5:-5], atol=1e-12)
    assert torch.allclose(_gaussian_blur(torch.full((2, 3, 9, 7), 0.25), 2.0, 2.0), torch.tensor(0.25), atol=1e-7)


def test_boundary_mask_of_a_window_is_the_crop_of_the_whole_mask(room_clip):
    cfg = QuerySamplerConfig(boundary_radius=2)
    whole = boundary_mask(room_clip, cfg).numpy()
    part = boundary_mask(room_clip, cfg, frames=[1, 5], window=(7, 3, 30, 20)).numpy()
    assert np.array_equal(part, whole[[1, 5], 3:23, 7:37])


def test_boundary_mask_marks_depth_and_motion_edges_only(room_clip):
    mask = boundary_mask(room_clip, QuerySamplerConfig(boundary_radius=0)).numpy()
    ids = room_clip.object_ids.astype(int)
    id_edge = np.zeros_like(mask)
    id_edge[:, :, 1:] |= ids[:, :, 1:] != ids[:, :, :-1]
    id_edge[:, :, :-1] |= ids[:, :, 1:] != ids[:, :, :-1]
    id_edge[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    id_edge[:, :-1] |= ids[:, 1:] != ids[:, :-1]
    # Most object-boundary pixels are depth or motion edges, and the band is a small part of the frame.
    assert mask[id_edge].mean() > 0.6
    assert 0.02 < mask.mean() < 0.5
    wide = boundary_mask(room_clip, QuerySamplerConfig(boundary_radius=2)).numpy()
    assert wide.mean() > mask.mean() and (wide | ~mask).all()  # dilation contains the thin mask


def test_sampler_statistics_match_the_paper(room_clip):
    cfg = QuerySamplerConfig(num_queries=20000)
    sampler = QuerySampler(cfg)
    band = boundary_mask(room_clip, cfg).numpy()
    out = sampler.sample(room_clip, np.random.default_rng(0))
    q = out["queries"]
    t = room_clip.num_frames
    # 30% drawn from the boundary band (exactly, as a count), the rest uniform over the frame.
    assert abs(out["from_boundary"].mean() - 0.3) < 1e-3
    col = np.floor(q[:, 0] * room_clip.width).astype(int)
    row = np.floor(q[:, 1] * room_clip.height).astype(int)
    in_band = band[q[:, 2].astype(int), row, col]
    assert in_band[out["from_boundary"]].all()
    expected = 0.3 + 0.7 * band.mean()  # uniform draws land in the band at its area fraction
    assert abs(in_band.mean() - expected) < 0.02, (in_band.mean(), expected)
    # t_tgt = t_cam forced with probability 0.4; otherwise the three times are independent uniforms.
    forced = out["forced_tgt_equals_cam"]
    assert abs(forced.mean() - 0.4) < 0.015
    equal = q[:, 3] == q[:, 4]
    assert abs(equal.mean() - (0.4 + 0.6 / t)) < 0.015
    for col_i in (2, 3, 4):
        counts = np.bincount(q[:, col_i].astype(int), minlength=t) / len(q)
        assert np.abs(counts - 1 / t).max() < 0.012


def test_object_fraction_draws_body_pixels_and_leaves_the_paper_stream_alone(room_clip):
    """object_fraction: that share of the queries (exactly, as a count, disjoint from the boundary draws) lies
    on foreground bodies, inside a view's crop too; at 0 the sampler draws exactly the paper's queries."""
    paper = QuerySampler(QuerySamplerConfig(num_queries=4000)).sample(room_clip, np.random.default_rng(3))
    off = QuerySampler(QuerySamplerConfig(num_queries=4000, object_fraction=0.0)).sample(room_clip,
                                                                                       np.random.default_rng(3))
    assert np.array_equal(paper["queries"], off["queries"]) and not off["from_object"].any()
    view = View((48, 64), (8, 4, 48, 40), (40, 48), (1, 2, 4, 5))
    out = QuerySampler(QuerySamplerConfig(num_queries=4000, object_fraction=0.25)).sample(
        room_clip, np.random.default_rng(3), view)
    assert out["from_object"].sum() == 1000 and not (out["from_object"] & out["from_boundary"]).any()
    source = out["source_queries"]
    col = np.floor(source[:, 0] * room_clip.width).astype(int)
    row = np.floor(source[:, 1] * room_clip.height).astype(int)
    on_body = room_clip.object_ids[source[:, 2].astype(int), row, col] > 0
    assert on_body[out["from_object"]].all()
    assert ((col >= 8) & (col < 56) & (row >= 4) & (row < 44)).all()  # inside the crop
    uniform = ~out["from_object"] & ~out["from_boundary"]
    assert on_body[out["from_object"]].mean() > on_body[uniform].mean() + 0.3  # bodies are a minority of pixels
    with pytest.raises(UserError, match="object_fraction"):
        QuerySampler(QuerySamplerConfig(object_fraction=1.5))


def test_training_sample_targets_are_exact_through_crop_zoom_and_stride(room_clip):
    rng = np.random.default_rng(1)
    sampler = QuerySampler(QuerySamplerConfig(num_queries=500))
    for zoom in (0.0, 1.0):
        aug = AugmentConfig(zoom_prob=zoom, max_stride=2)
        view = sample_view(rng, room_clip.num_frames, (48, 64), 4, (32, 32), aug)
        sample = make_training_sample(room_clip, view, rng, sampler, aug)
        child = room_clip.view(view)  # the same view as a clip: its oracle must give the same targets
        q = sample["queries"].double().numpy()
        ref = child.oracle.query(q)
        assert torch.allclose(sample["points"], ref["points"].float(), atol=1e-5)
        assert torch.allclose(sample["visibility"], ref["visibility"].float())
        # The body each query's point lies on (loss.weight_body_relative_depth): the source pixel's object id.
        assert sample["object_id"].dtype == torch.int64 and torch.equal(sample["object_id"], ref["object_id"].long())
        assert (sample["object_id"] > 0).any() and (sample["object_id"] == 0).any()
        ok = ref["uv_valid"]
        assert torch.allclose(sample["uv"][ok], ref["uv"][ok].float(), atol=1e-5)
        # Targets at t_tgt = t_cam project through the sample's intrinsics onto the sample's uv.
        same = (q[:, 3] == q[:, 4]) & ok.numpy()
        k = sample["intrinsics"].double().numpy()[q[same, 3].astype(int)]
        xy, _ = project(sample["points"].double().numpy()[same], k)
        uv = np.stack([(xy[:, 0] + 0.5) / 32, (xy[:, 1] + 0.5) / 32], 1)
        assert np.abs(uv - sample["uv"].double().numpy()[same]).max() < 1e-4
        assert sample["video"].shape == (4, 32, 32, 3) and 0 <= sample["video"].min() <= sample["video"].max() <= 1
        x0, y0, w, h = view.crop
        assert sample["aspect_ratio"].item() == pytest.approx(w / h)
        # Each sample pixel's depth is the source depth at the source pixel under its centre (nearest, no blend).
        rows = y0 + np.minimum(((np.arange(32) + 0.5) * h / 32).astype(int), h - 1)
        cols = x0 + np.minimum(((np.arange(32) + 0.5) * w / 32).astype(int), w - 1)
        source = room_clip.depth[list(view.frames)][:, rows][:, :, cols]
        assert torch.equal(sample["depth"], torch.from_numpy(np.where(source > 0, source, 0).astype(np.float32)))


def test_sample_view_ranges():
    rng = np.random.default_rng(2)
    cfg = AugmentConfig()
    areas, aspects, strides = [], [], []
    for _ in range(2000):
        v = sample_view(rng, 48, (90, 160), 16, (64, 64), cfg)
        x0, y0, w, h = v.crop
        areas.append(w * h / (90 * 160))
        aspects.append(w / h)
        strides.append(v.frames[1] - v.frames[0])
        assert v.frames[-1] < 48 and x0 + w <= 160 and y0 + h <= 90
    areas = np.array(areas)
    assert areas.min() >= 0.03 and areas.max() <= 1.0
    assert 0.9 < np.mean((areas > 0.29) & (areas < 1.01)) < 0.99  # crops; the rest are zoom-ins (p 0.05)
    assert set(strides) == {1, 2, 3}
    assert min(aspects) < 0.6 and max(aspects) > 1.8


def test_photometric_augment_is_consistent_over_time_and_bounded():
    rng = np.random.default_rng(3)
    frame = torch.rand(1, 16, 16, 3)
    video = frame.repeat(4, 1, 1, 1)
    cfg = AugmentConfig(jitter_prob=1.0, color_drop_prob=0.0, blur_prob=1.0)
    out = photometric_augment(video, rng, cfg)
    assert out.shape == video.shape and 0 <= out.min() and out.max() <= 1
    assert torch.allclose(out[0], out[3])  # identical frames stay identical: one draw per clip
    assert not torch.allclose(out, video)
    gray = photometric_augment(video, rng, AugmentConfig(jitter_prob=0.0, color_drop_prob=1.0, blur_prob=0.0))
    assert torch.allclose(gray[..., 0], gray[..., 1]) and torch.allclose(gray[..., 1], gray[..., 2])


def test_datasets_render_on_the_fly_or_read_files_deterministically(tmp_path, room_clip):
    cfg = DatasetConfig(num_clips=3, frames=4, size=(32, 32), render_pixels=40 * 40,
                        sampler=QuerySamplerConfig(num_queries=64))
    ds = ClipQueryDataset(cfg)
    a, b = ds[1], ds[1]
    for key in a:
        assert torch.equal(a[key], b[key]), key
    assert a["video"].shape == (4, 32, 32, 3) and a["queries"].shape == (64, 5) and a["points"].shape == (64, 3)
    assert torch.isfinite(a["points"]).all()
    ds.set_epoch(1)
    assert not torch.equal(ds[1]["queries"], a["queries"])
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=2)))
    assert batch["video"].shape == (2, 4, 32, 32, 3)
    # From files, including clips without a scene description (bring-your-own-data layout).
    room_clip.save(tmp_path / "a.npz")
    Clip(room_clip.rgb, room_clip.depth, room_clip.normals, room_clip.object_ids, room_clip.intrinsics,
         room_clip.cam_to_world, room_clip.object_to_world).save(tmp_path / "b.npz")
    files = ClipQueryDataset(DatasetConfig(source="files", directory=str(tmp_path), frames=4, size=(32, 32),
                                           sampler=QuerySamplerConfig(num_queries=64)))
    assert len(files) == 2
    for i in range(2):
        s = files[i]
        assert s["queries"].shape == (64, 5) and s["valid"].any()
    with pytest.raises(UserError, match="no .npz clips"):
        ClipQueryDataset(DatasetConfig(source="files", directory=str(tmp_path / "empty")))


def _crop_geometry(policy: str, jitter: float = 0.05, n: int = 3000):
    """Principal-point offsets (fraction of the view, from its centre) and horizontal FOVs (degrees) of
    the views ``sample_view`` draws from 96x96 frames whose camera has a 60-degree FOV, centred."""
    rng = np.random.default_rng(3)
    cfg = AugmentConfig(crop_policy=policy, center_jitter=jitter)
    source = np.array([[[48 / np.tan(np.radians(30)), 0, 47.5], [0, 48 / np.tan(np.radians(30)), 47.5],
                        [0, 0, 1]]] * 8)
    offsets, fovs, bounds = [], [], []
    for _ in range(n):
        view = sample_view(rng, 8, (96, 96), 8, (64, 64), cfg)
        k = view.intrinsics(source)[0]
        offsets.append(((k[0, 2] + 0.5) / 64 - 0.5, (k[1, 2] + 0.5) / 64 - 0.5))
        fovs.append(np.degrees(2 * np.arctan(32 / k[0, 0])))
        # The crop's centre may sit jitter * 96 pixels (+ half a pixel of rounding) off the frame's
        # centre: that many source pixels, as a fraction of the crop's width / height.
        _, _, w, h = view.crop
        bounds.append(((jitter * 96 + 0.5) / w, (jitter * 96 + 0.5) / h))
    return np.abs(np.array(offsets)), np.array(fovs), np.array(bounds)


def test_crop_policies_keep_the_principal_point_and_field_of_view_in_their_ranges():
    # The paper's crops: anywhere in the frame, so the principal point wanders far from the centre.
    offsets, fovs, _ = _crop_geometry("paper")
    assert np.percentile(offsets, 90) > 0.25
    # Centred crops: the principal point within the configured jitter of the view's centre; crop sizes
    # (hence FOVs) are drawn as in the paper.
    offsets_c, fovs_c, bounds = _crop_geometry("centered")
    assert (offsets_c <= bounds + 1e-9).all()
    assert np.percentile(offsets_c, 90) < 0.1 and np.percentile(offsets, 90) > 2.5 * np.percentile(offsets_c, 90)
    # A crop narrows the FOV: at least to 2 atan(sqrt(0.05 * 0.5) tan 30°) = 10.4° (the smallest zoom-in
    # at the narrowest aspect), never wider than the camera's. Both policies draw the same sizes.
    narrowest = np.degrees(2 * np.arctan(np.sqrt(0.05 * 0.5) * np.tan(np.radians(30))))
    for f in (fovs, fovs_c):
        assert narrowest - 0.5 <= f.min() and f.max() <= 60 + 1e-6 and 35 < np.median(f) < 55
    assert abs(np.median(fovs) - np.median(fovs_c)) < 1.5
    # No crop: the camera's own principal point and FOV, every time.
    offsets_n, fovs_n, _ = _crop_geometry("none", n=50)
    assert offsets_n.max() < 1e-9 and np.allclose(fovs_n, 60)
    with pytest.raises(UserError, match="crop_policy"):
        AugmentConfig(crop_policy="middle").validate()
    with pytest.raises(UserError, match="center_jitter"):
        AugmentConfig(center_jitter=0.7).validate()


def test_variable_clip_lengths_and_depth_queries(tmp_path):
    cfg = DatasetConfig(num_clips=40, frames=4, frame_choices=(2, 4, 6), size=(32, 32), render_pixels=32 * 32,
                        sampler=QuerySamplerConfig(num_queries=200, depth_fraction=0.5))
    ds = ClipQueryDataset(cfg)
    lengths = {ds[i]["video"].shape[0] for i in range(12)}
    assert lengths == {2, 4, 6} and cfg.max_frames == 6
    q = ds[0]["queries"]
    depth = (q[:, 2] == q[:, 3]) & (q[:, 3] == q[:, 4])
    assert 0.35 < depth.float().mean() < 0.7  # 0.5 forced + the uniform draws' own share
    # Camera-pair queries: t_tgt = t_src and t_cam a neighbouring frame, at about the asked share.
    cfg = DatasetConfig(num_clips=4, frames=5, size=(32, 32), render_pixels=32 * 32,
                        sampler=QuerySamplerConfig(num_queries=400, adjacent_camera_fraction=0.6))
    q = ClipQueryDataset(cfg)[0]["queries"]
    pair = (q[:, 2] == q[:, 3]) & ((q[:, 4] - q[:, 2]).abs() == 1)
    assert 0.5 < pair.float().mean() < 0.75 and q[:, 2:].min() >= 0 and q[:, 2:].max() <= 4
    with pytest.raises(UserError, match="adjacent_camera_fraction"):
        QuerySamplerConfig(adjacent_camera_fraction=1.5).validate()
    # Pairs over gaps of up to k frames: every gap 1..k drawn, each inside the clip, even where only one side fits.
    cfg = DatasetConfig(num_clips=4, frames=5, size=(32, 32), render_pixels=32 * 32,
                        sampler=QuerySamplerConfig(num_queries=2000, adjacent_camera_fraction=1.0,
                                                   camera_pair_max_gap=3))
    q = ClipQueryDataset(cfg)[0]["queries"]
    gaps = (q[:, 4] - q[:, 2]).abs()
    assert (q[:, 2] == q[:, 3]).all() and set(gaps.long().tolist()) == {1, 2, 3}
    assert q[:, 2:].min() >= 0 and q[:, 2:].max() <= 4
    assert gaps[q[:, 2] == 2].max() == 2  # the middle of 5 frames: no gap of 3 fits either side
    with pytest.raises(UserError, match="camera_pair_max_gap must be an integer >= 1"):
        QuerySamplerConfig(camera_pair_max_gap=0).validate()
    from d4rt.training import TrainConfig

    config = TrainConfig.from_dict({"data": {"batch_size": 2, "dataset": {"frames": 8, "frame_choices": [8, 16],
                                                                          "size": [64, 64]}}})
    with pytest.raises(UserError, match="frame_choices needs data.batch_size 1"):
        config.validate()


def test_render_device_is_checked_and_spawned_workers_give_the_same_batches():
    with pytest.raises(UserError, match="render_device must be"):
        DatasetConfig(render_device="gpu")
    small = dict(num_clips=4, frames=3, size=(24, 24), render_pixels=24 * 24,
                 sampler=QuerySamplerConfig(num_queries=32))
    if not torch.cuda.is_available():  # a GPU config read on a CPU machine fails when the dataset is built
        config = DatasetConfig(render_device="cuda", **small)
        assert config.renders_on_gpu
        with pytest.raises(UserError, match="no such CUDA device"):
            ClipQueryDataset(config)
    assert not DatasetConfig(source="files", render_device="cuda", directory="x").renders_on_gpu
    # The loader's spawn start (what a GPU-rendering dataset gets) yields exactly the forked workers' batches.
    from d4rt.training.data import SampleStream, training_loader

    dataset = ClipQueryDataset(DatasetConfig(render_device="cpu", **small))
    batches = []
    for spawn in (False, True):
        stream = SampleStream(len(dataset), 3, 0, 1, 1, 0, 1)
        loader = iter(training_loader(dataset, stream, 1, 3, 0, pin_memory=False, spawn=spawn))
        batches.append([next(loader) for _ in range(2)])
        del loader
    for forked, spawned in zip(*batches):
        for key in forked:
            assert torch.equal(forked[key], spawned[key]), key


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_clip_rendered_on_the_gpu_matches_the_cpu_render():
    from d4rt.synthetic.generate import render_clip

    cpu, gpu = (render_clip(11, 3, 40, 48, device=device) for device in ("cpu", "cuda"))
    # The same geometry to float rounding (a silhouette pixel may flip between bodies: allow a few).
    same = np.isclose(cpu.depth, gpu.depth, rtol=1e-4) & (cpu.object_ids == gpu.object_ids)
    assert same.mean() > 0.99
    assert np.abs(cpu.rgb.astype(int) - gpu.rgb.astype(int))[same].mean() < 1.0


def test_echo_draws_several_samples_from_one_render(monkeypatch):
    import d4rt.data.dataset as dataset_module

    renders = []
    real_render = dataset_module.render_clip
    monkeypatch.setattr(dataset_module, "render_clip", lambda *a, **k: renders.append(a[0]) or real_render(*a, **k))
    options = dict(num_clips=5, frames=4, size=(32, 32), render_pixels=32 * 32,
                   sampler=QuerySamplerConfig(num_queries=64))
    plain, echoed = ClipQueryDataset(DatasetConfig(**options)), ClipQueryDataset(DatasetConfig(echo=3, **options))
    first = echoed.sample(2, 0)
    for key, value in plain[2].items():  # repeat 0 is the plain stream's sample
        assert torch.equal(first[key], value), key
    renders.clear()
    samples = [echoed.sample(2, r) for r in (0, 1, 2)]
    assert len(renders) == 0  # the clip rendered for `first` serves every repeat of index 2
    again = echoed.sample(2, 1)
    assert torch.equal(again["queries"], samples[1]["queries"])  # deterministic per (index, repeat)
    assert not torch.equal(samples[1]["queries"], samples[0]["queries"])
    assert not torch.equal(samples[2]["queries"], samples[1]["queries"])
    echoed.sample(3, 0)
    assert len(renders) == 1  # a new clip, rendered once
    with pytest.raises(IndexError, match="repeat 3 out of range"):
        echoed.sample(2, 3)
    with pytest.raises(UserError, match="echo must be a positive integer"):
        DatasetConfig(echo=0)


def test_camera_pair_twins_are_the_pairs_pixel_in_its_own_camera_and_rigidly_related():
    cfg = DatasetConfig(num_clips=2, frames=6, size=(32, 32), render_pixels=32 * 32,
                        sampler=QuerySamplerConfig(num_queries=300, adjacent_camera_fraction=0.3,
                                                   camera_pair_twins=True))
    sample = ClipQueryDataset(cfg)[0]
    q, twin, points = sample["queries"].double(), sample["twin"], sample["points"].double()
    pairs = torch.nonzero(twin >= 0)[:, 0]
    assert 50 < len(pairs) < 130 and (twin >= 0).sum() == len(set(twin[pairs].tolist()))  # one twin each
    mates = twin[pairs]
    assert not (twin[mates] >= 0).any()  # a twin is not itself a pair
    assert torch.equal(q[pairs, :3], q[mates, :3]) and (q[pairs, 3] == q[pairs, 2]).all()
    assert ((q[pairs, 4] - q[pairs, 2]).abs() == 1).all() and (q[mates, 4] == q[mates, 2]).all()
    assert (q[mates, 3] == q[mates, 2]).all()
    # The same surface point at the same time in two cameras: P_pair = R P_twin + t, exactly (float32 targets).
    ok = sample["valid"][pairs] & sample["valid"][mates]
    c2w = sample["cam_to_world"].double()
    src, cam = q[pairs, 2].long(), q[pairs, 4].long()
    relative = torch.linalg.inv(c2w[cam]) @ c2w[src]
    moved = (relative[:, :3, :3] @ points[mates][..., None])[..., 0] + relative[:, :3, 3]
    assert ok.sum() > 30 and (moved - points[pairs])[ok].abs().max() < 1e-4
    # Off by default: the paper's stream has no twins; twins without pairs are refused.
    assert "twin" not in ClipQueryDataset(DatasetConfig(num_clips=1, frames=3, size=(16, 16),
                                                        render_pixels=256))[0]
    with pytest.raises(UserError, match="camera_pair_twins needs adjacent_camera_fraction"):
        QuerySamplerConfig(camera_pair_twins=True).validate()
