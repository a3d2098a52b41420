"""The paper's losses: hand-computed values, scale invariance, masks, finite gradients."""

import math

import pytest
import torch

from d4rt.errors import UserError
from d4rt.training import LossConfig, d4rt_loss, log_compress, mean_depth, point_loss
from d4rt.training.losses import ray_angle_loss

LOG2 = math.log(2.0)


def perfect(batch):
    """Predictions equal to the targets (every term 0 except BCE and the confidence terms)."""
    n = batch["points"].shape[1]
    return {
        "points": batch["points"].clone(),
        "uv": batch["uv"].clone(),
        "visibility_logit": torch.full((1, n), 30.0) * (2 * batch["visibility"] - 1),  # BCE ~ 1e-13
        "motion": batch["motion"].clone(),
        "normals": batch["normals"].clone(),
        "confidence": torch.ones(1, n),
    }


def two_query_batch():
    return {
        "points": torch.tensor([[[0.0, 0.0, 4.0], [0.0, 0.0, 4.0]]]),
        "uv": torch.tensor([[[0.25, 1.0], [0.5, 0.5]]]),
        "visibility": torch.tensor([[1.0, 0.0]]),
        "motion": torch.tensor([[[2.0, 0.0, 0.0], [0.0, 0.0, 0.0]]]),
        "normals": torch.tensor([[[0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]]),
        "valid": torch.tensor([[True, True]]),
        "uv_valid": torch.tensor([[True, True]]),
    }


def test_log_compress_and_mean_depth_by_hand():
    torch.testing.assert_close(log_compress(torch.tensor([-3.0, 0.0, 1.0])), torch.tensor([-math.log(4.0), 0.0, LOG2]))
    points = torch.tensor([[[5.0, 1.0, 2.0], [0.0, 0.0, -4.0], [9.0, 9.0, 100.0]]])
    # |z| over the valid queries: (2 + 4) / 2; the third is masked out.
    torch.testing.assert_close(mean_depth(points, torch.tensor([[True, True, False]])), torch.tensor([3.0]))


def test_point_loss_by_hand():
    # pred: mean |z| = 2 -> (0,0,1), (1,0,1); target: mean |z| = 4 -> (0,0,1), (0,0,1).
    pred = torch.tensor([[[0.0, 0.0, 2.0], [2.0, 0.0, 2.0]]])
    target = torch.tensor([[[0.0, 0.0, 4.0], [0.0, 0.0, 4.0]]])
    l3d = point_loss(pred, target, torch.ones(1, 2, dtype=torch.bool))
    torch.testing.assert_close(l3d, torch.tensor([[0.0, LOG2]]))  # |log(1 + 1) - log(1 + 0)| in x only


def test_every_term_by_hand():
    batch = two_query_batch()
    pred = perfect(batch)
    pred["points"] = torch.tensor([[[0.0, 0.0, 2.0], [2.0, 0.0, 2.0]]])  # L3D per query: 0, log 2
    pred["confidence"] = torch.tensor([[1.0, 2.0]])
    pred["uv"] = torch.tensor([[[0.5, 0.5], [0.5, 0.5]]])  # L1 per query: 0.25 + 0.5, 0
    pred["visibility_logit"] = torch.tensor([[0.0, 0.0]])  # BCE: log 2 each
    pred["motion"] = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])  # /2 vs target /4: 0, then 1/2
    pred["normals"] = torch.tensor([[[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]]])  # 1 - cos: 1, 0
    total, terms = d4rt_loss(pred, batch)
    expected = {"3d": LOG2 / 2, "3d_confident": (0 + 2 * LOG2) / 2, "confidence": -LOG2 / 2, "2d": 0.75 / 2,
                "visibility": LOG2, "motion": 0.5 / 2, "normal": 0.5, "confidence_mean": 1.5}
    for key, value in expected.items():
        assert terms[key].item() == pytest.approx(value, rel=1e-6), key
    paper = (1.0 * LOG2 - 0.2 * LOG2 / 2 + 0.1 * 0.375 + 0.1 * LOG2 + 0.1 * 0.25 + 0.5 * 0.5)
    assert total.item() == pytest.approx(paper, rel=1e-6)
    assert terms["total"].item() == pytest.approx(paper, rel=1e-6)


def test_weights_and_confidence_switch():
    batch = two_query_batch()
    pred = perfect(batch)
    pred["points"] = torch.tensor([[[0.0, 0.0, 2.0], [2.0, 0.0, 2.0]]])
    pred["confidence"] = torch.tensor([[1.0, 2.0]])
    plain, _ = d4rt_loss(pred, batch, LossConfig(confidence_weighting=False, weight_visibility=0.0, weight_motion=0.0))
    assert plain.item() == pytest.approx(LOG2 / 2, rel=1e-6)  # plain L3D: confidence ignored
    doubled, _ = d4rt_loss(pred, batch, LossConfig(weight_3d=2.0, weight_visibility=0.0, weight_motion=0.0))
    assert doubled.item() == pytest.approx(2 * LOG2 - 0.2 * LOG2 / 2, rel=1e-6)


def test_confidence_stop_gradient_splits_the_gradients():
    """Points get plain L3D's gradient, the confidence the paper's; a bad combination is refused."""
    batch = two_query_batch()

    def gradients(config):
        pred = perfect(batch)
        pred["points"] = torch.tensor([[[0.0, 0.0, 2.0], [2.0, 0.0, 2.0]]], requires_grad=True)
        pred["confidence"] = torch.tensor([[1.0, 2.0]], requires_grad=True)
        total, terms = d4rt_loss(pred, batch, config)
        total.backward()
        return total, terms, pred["points"].grad, pred["confidence"].grad

    quiet = dict(weight_visibility=0.0, weight_motion=0.0)
    total, terms, points_grad, confidence_grad = gradients(LossConfig(confidence_stop_gradient=True, **quiet))
    _, _, plain_points_grad, _ = gradients(LossConfig(confidence_weighting=False, **quiet))
    _, paper_terms, paper_points_grad, paper_confidence_grad = gradients(LossConfig(**quiet))
    torch.testing.assert_close(points_grad, plain_points_grad)
    torch.testing.assert_close(confidence_grad, paper_confidence_grad)
    assert not torch.allclose(points_grad, paper_points_grad)  # c = 2 doubled the paper's gradient there
    assert total.item() == pytest.approx(LOG2 / 2 + LOG2 - 0.2 * LOG2 / 2, rel=1e-6)  # L3D + c L3D - w log c
    assert terms["3d_confident"].item() == pytest.approx(paper_terms["3d_confident"].item())
    with pytest.raises(UserError, match="confidence_stop_gradient needs confidence_weighting"):
        LossConfig(confidence_weighting=False, confidence_stop_gradient=True).validate()


def test_log_depth_term_by_hand_scale_invariant_and_masked():
    """|log(z_pred / s_pred) - log(z_target / s_target)| over the targets in front of the camera."""
    batch = two_query_batch()
    batch["points"] = torch.tensor([[[0.0, 0.0, 2.0], [0.0, 0.0, 6.0], [0.0, 0.0, -4.0]]])  # mean |z| = 4
    for key, value in {"uv": torch.zeros(1, 3, 2), "visibility": torch.zeros(1, 3), "motion": torch.zeros(1, 3, 3),
                       "normals": torch.zeros(1, 3, 3), "valid": torch.ones(1, 3, dtype=torch.bool),
                       "uv_valid": torch.zeros(1, 3, dtype=torch.bool)}.items():
        batch[key] = value
    pred = perfect(batch)
    # pred mean |z| = 4 as well: query 0 is 2x too near, query 1 right; query 2 (behind camera) is not counted.
    pred["points"] = torch.tensor([[[0.0, 0.0, 1.0], [0.0, 0.0, 6.0], [0.0, 0.0, -5.0]]], requires_grad=True)
    config = LossConfig(weight_log_depth=0.5)
    total, terms = d4rt_loss(pred, batch, config)
    assert terms["log_depth"].item() == pytest.approx(LOG2 / 2, rel=1e-6)
    without, off_terms = d4rt_loss(pred, batch, LossConfig())
    assert "log_depth" not in off_terms
    assert (total - without).item() == pytest.approx(0.5 * LOG2 / 2, rel=1e-5)
    total.backward()
    assert torch.isfinite(pred["points"].grad).all()
    for scale in (1e-3, 7.0, 1e4):  # invariant to a positive scale of the prediction
        scaled = perfect(batch) | {"points": pred["points"].detach() * scale}
        assert d4rt_loss(scaled, batch, config)[1]["log_depth"].item() == pytest.approx(LOG2 / 2, rel=1e-5)
    with pytest.raises(UserError, match="weight_log_depth must be a number >= 0"):
        LossConfig(weight_log_depth=-1.0).validate()


def test_ray_angle_term_by_hand_scale_invariant_and_masked():
    """The angle between predicted and true point over the clip's mean angle of its in-front targets."""
    target = torch.tensor([[[0.0, 0.0, 2.0], [2.0, 0.0, 2.0], [0.0, 0.0, -3.0], [0.0, 0.0, 0.0]]])
    # In-front targets lie 0 and 45 degrees off the axis: the spread is 22.5 degrees.
    pred = torch.tensor([[[1.0, 0.0, 1.0], [4.0, 0.0, 4.0], [0.0, 3.0, 0.0], [1.0, 1.0, 1.0]]])
    mask = torch.tensor([[True, True, True, True]])
    error, defined = ray_angle_loss(pred, target, mask)
    assert defined.tolist() == [[True, True, True, False]]  # the last target is missing (zeroed)
    torch.testing.assert_close(error[0, :3], torch.tensor([2.0, 0.0, 4.0]))  # 45, 0, 90 degrees over 22.5
    for pred_scale, target_scale in ((1e-3, 1.0), (1.0, 7.0), (1e4, 0.01)):
        scaled, _ = ray_angle_loss(pred * pred_scale, target * target_scale, mask)
        torch.testing.assert_close(scaled[defined], error[defined])
    batch = two_query_batch()
    batch["points"] = torch.tensor([[[1.0, 0.0, 4.0], [-1.0, 0.5, 4.0]]])
    pred_dict = perfect(batch)
    pred_dict["points"] = (batch["points"] * torch.tensor([1.3, 1.3, 1.0])).requires_grad_(True)  # wider view
    total, terms = d4rt_loss(pred_dict, batch, LossConfig(weight_ray_angle=2.0))
    without, off_terms = d4rt_loss(pred_dict, batch, LossConfig())
    assert "ray_angle" not in off_terms and terms["ray_angle"].item() > 0
    assert (total - without).item() == pytest.approx(2.0 * terms["ray_angle"].item(), rel=1e-5)
    with pytest.raises(UserError, match="weight_ray_angle must be a number >= 0"):
        LossConfig(weight_ray_angle=-0.5).validate()


def test_ray_angle_term_prices_a_focal_error_alike_at_every_field_of_view():
    """A 40% focal error costs the ray-angle term about the same in a 30- and a 100-degree view (a third more
    in the narrow one), while L3D prices the narrow view's error three times lower (why the term exists:
    module docstring)."""
    generator = torch.Generator().manual_seed(0)
    pixels = torch.rand(1, 2000, 2, generator=generator) * 2 - 1  # normalised image coordinates in [-1, 1]
    depth = 1 + 4 * torch.rand(1, 2000, generator=generator)
    mask = torch.ones(1, 2000, dtype=torch.bool)
    ray_costs, l3d_costs = [], []
    for fov in (30.0, 100.0):
        half_width = math.tan(math.radians(fov / 2))
        target = torch.cat([pixels * half_width * depth[..., None], depth[..., None]], -1)
        pred = torch.cat([pixels * half_width / 1.4 * depth[..., None], depth[..., None]], -1)  # focal 1.4x
        ray_costs.append(ray_angle_loss(pred, target, mask)[0].mean().item())
        l3d_costs.append(point_loss(pred, target, mask).mean().item())
    assert ray_costs[1] < ray_costs[0] < 1.5 * ray_costs[1]
    assert l3d_costs[1] > 2.5 * l3d_costs[0]


ANGLES = torch.linspace(0.01, 0.3, 50)  # radians off the axis


def rays_at(scale: float) -> torch.Tensor:
    """Unit rays in the x-z plane at ``scale`` times ANGLES off the axis: (1, 50, 3)."""
    return torch.stack([torch.sin(scale * ANGLES), torch.zeros_like(ANGLES), torch.cos(scale * ANGLES)], -1)[None]


def ray_angle_hedge(spread: str) -> float:
    """The angle scale c a model unsure whether a clip's true angles are 0.5x or 2x (even odds) should answer
    to minimise the ray-angle term: the argmin over a grid of the term's mean over both cases."""
    mask = torch.ones(1, 50, dtype=torch.bool)
    grid = torch.logspace(-1, 1, 81, base=2.0).tolist()  # 0.5 ... 2
    costs = [sum(ray_angle_loss(rays_at(c), rays_at(s), mask, spread)[0].mean().item() for s in (0.5, 2.0))
             for c in grid]
    return grid[costs.index(min(costs))]


def test_ray_angle_geometric_spread_prices_too_wide_and_too_narrow_alike():
    """Over the true spread alone, reading angles 2x too wide costs twice what 0.5x costs, so an unsure model
    hedges all the way narrow (focal long); over both spreads the costs are equal and the hedge is centred."""
    mask = torch.ones(1, 50, dtype=torch.bool)
    costs = {(spread, k): ray_angle_loss(rays_at(k), rays_at(1.0), mask, spread)[0].mean().item()
             for spread in ("target", "geometric") for k in (0.5, 2.0)}
    assert costs["target", 2.0] == pytest.approx(2 * costs["target", 0.5], rel=1e-3)
    assert costs["geometric", 2.0] == pytest.approx(costs["geometric", 0.5], rel=1e-3)
    assert ray_angle_hedge("target") == pytest.approx(0.5)
    assert ray_angle_hedge("geometric") == pytest.approx(1.0)
    with pytest.raises(UserError, match="ray_angle_spread must be one of target, geometric"):
        LossConfig(ray_angle_spread="predicted").validate()
    with pytest.raises(UserError, match="ray-angle spread must be one of target, geometric"):
        ray_angle_loss(rays_at(1.0), rays_at(1.0), mask, "geometic")


@pytest.mark.parametrize("spread", ["target", "geometric"])
def test_ray_angle_gradients_are_finite_with_missing_targets_and_zero_predictions(spread):
    target = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 2.0], [1.0, 0.0, 2.0]]])
    pred = torch.tensor([[[1.0, 0.0, 1.0], [0.0, 0.0, 0.0], [2.0, 0.0, 4.0]]], requires_grad=True)
    mask = torch.tensor([[False, True, True]])
    error, defined = ray_angle_loss(pred, target, mask, spread)
    assert defined.tolist() == [[False, False, True]]
    torch.where(defined, error, torch.zeros_like(error)).sum().backward()
    assert torch.isfinite(pred.grad).all()


@pytest.mark.parametrize("scale", [1e-3, 0.37, 7.0, 1e4])
def test_l3d_is_invariant_to_scaling_prediction_or_target(scale):
    g = torch.Generator().manual_seed(0)
    pred = torch.randn(2, 50, 3, generator=g) + torch.tensor([0.0, 0.0, 3.0])
    target = torch.randn(2, 50, 3, generator=g) * 2 + torch.tensor([0.0, 0.0, 8.0])
    mask = torch.rand(2, 50, generator=g) > 0.2
    base = point_loss(pred, target, mask)
    torch.testing.assert_close(point_loss(pred * scale, target, mask), base, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(point_loss(pred, target * scale, mask), base, rtol=1e-5, atol=1e-6)
    # Per clip: scaling one clip of the batch does not change the other's loss either.
    per_clip = torch.tensor([scale, 1.0])[:, None, None]
    torch.testing.assert_close(point_loss(pred * per_clip, target, mask), base, rtol=1e-5, atol=1e-6)


def test_masks_exclude_missing_ground_truth():
    """Anything under a False mask, even NaN targets or absurd predictions, changes neither loss nor gradient."""
    batch = two_query_batch()
    pred = perfect(batch)
    pred["confidence"] = torch.tensor([[1.0, 2.0]])
    reference, ref_terms = d4rt_loss(pred, batch)

    # A third query without any ground truth: NaN targets, wild predictions.
    batch3 = {k: torch.cat([v, v[:, :1]], 1) for k, v in batch.items()}
    batch3["valid"][0, 2] = batch3["uv_valid"][0, 2] = False
    for key in ("points", "uv", "visibility", "motion", "normals"):
        batch3[key][0, 2] = float("nan")
    pred3 = {k: torch.cat([v, v[:, :1]], 1) for k, v in pred.items()}
    pred3["points"][0, 2] = torch.tensor([1e6, -1e6, 1e6])
    pred3["uv"][0, 2] = 50.0
    pred3["visibility_logit"][0, 2] = -40.0
    pred3 = {k: v.requires_grad_() for k, v in pred3.items()}
    total, terms = d4rt_loss(pred3, batch3)
    assert total.item() == pytest.approx(reference.item(), rel=1e-6)
    for key in ("3d", "3d_confident", "2d", "visibility", "motion", "normal", "confidence"):
        assert terms[key].item() == pytest.approx(ref_terms[key].item(), rel=1e-6, abs=1e-12), key
    total.backward()
    for key, tensor in pred3.items():
        assert torch.isfinite(tensor.grad).all(), key
        assert (tensor.grad[0, 2] == 0).all(), key


def test_behind_camera_point_supervises_visibility_but_not_uv():
    """A point behind camera t_tgt: valid (it exists) but uv_valid False. Its visibility target 0 is
    ground truth; its uv is undefined."""
    batch = two_query_batch()
    batch["uv_valid"][0, 1] = False
    batch["visibility"][0, 1] = 0.0
    pred = perfect(batch)
    _, base = d4rt_loss(pred, batch)
    moved_uv = {**pred, "uv": pred["uv"].clone()}
    moved_uv["uv"][0, 1] = torch.tensor([3.0, -2.0])
    assert d4rt_loss(moved_uv, batch)[1]["2d"].item() == pytest.approx(base["2d"].item(), abs=1e-12)
    wrong_vis = {**pred, "visibility_logit": pred["visibility_logit"].clone()}
    wrong_vis["visibility_logit"][0, 1] = 5.0  # says "visible"
    assert d4rt_loss(wrong_vis, batch)[1]["visibility"].item() > base["visibility"].item() + 1.0


def test_empty_masks_give_zero_terms_still_attached_to_the_graph():
    batch = two_query_batch()
    batch["valid"][:] = False
    batch["uv_valid"][:] = False
    pred = {k: v.clone().requires_grad_() for k, v in perfect(batch).items()}
    total, terms = d4rt_loss(pred, batch)
    assert total.item() == 0.0 and terms["valid_fraction"].item() == 0.0
    total.backward()  # DDP needs every head in the graph even when a batch has no ground truth
    assert all(torch.equal(p.grad, torch.zeros_like(p)) for p in pred.values())


@pytest.mark.parametrize("depth", [1e-6, 1e-3, 1.0, 1e3, 1e6, "mixed"])
def test_gradients_are_finite_for_tiny_and_huge_depths(depth):
    g = torch.Generator().manual_seed(1)
    n = 64
    if depth == "mixed":
        z = torch.where(torch.rand(1, n, generator=g) > 0.5, 1e-5, 1e5)
    else:
        z = torch.full((1, n), float(depth))
    xy = torch.randn(1, n, 2, generator=g) * z[..., None]
    target = torch.cat([xy, z[..., None]], -1)
    batch = {"points": target, "uv": torch.rand(1, n, 2, generator=g), "visibility": torch.ones(1, n),
             "motion": target * 0.1, "normals": torch.nn.functional.normalize(torch.randn(1, n, 3, generator=g), dim=-1),
             "valid": torch.ones(1, n, dtype=torch.bool), "uv_valid": torch.ones(1, n, dtype=torch.bool)}
    for scale in (1e-4, 1.0, 1e4):  # predictions far smaller or larger than the targets
        pred = {"points": torch.randn(1, n, 3, generator=g) * scale, "uv": torch.rand(1, n, 2, generator=g),
                "visibility_logit": torch.randn(1, n, generator=g), "motion": torch.randn(1, n, 3, generator=g) * scale,
                "normals": torch.nn.functional.normalize(torch.randn(1, n, 3, generator=g), dim=-1),
                "confidence": torch.rand(1, n, generator=g) + 1e-3}
        pred = {k: v.requires_grad_() for k, v in pred.items()}
        total, terms = d4rt_loss(pred, batch)
        total.backward()
        assert torch.isfinite(total) and all(torch.isfinite(v) for v in terms.values())
        for key, tensor in pred.items():
            assert torch.isfinite(tensor.grad).all(), (key, scale)


def test_all_zero_prediction_keeps_the_loss_finite():
    batch = two_query_batch()
    pred = {k: torch.zeros_like(v).requires_grad_() for k, v in perfect(batch).items()}
    pred["confidence"] = torch.ones(1, 2, requires_grad=True)
    total, _ = d4rt_loss(pred, batch)
    total.backward()
    assert torch.isfinite(total) and all(torch.isfinite(p.grad).all() for p in pred.values())


def test_bf16_predictions_are_computed_in_float32():
    batch = two_query_batch()
    pred = perfect(batch)
    pred["points"] = torch.tensor([[[0.0, 0.0, 2.0], [2.0, 0.0, 2.0]]])
    low = {k: v.to(torch.bfloat16) for k, v in pred.items()}
    total, _ = d4rt_loss(low, batch)
    assert total.dtype == torch.float32
    assert total.item() == pytest.approx(d4rt_loss(pred, batch)[0].item(), rel=1e-2)


def test_loss_config_rejects_bad_weights():
    from d4rt.errors import UserError

    with pytest.raises(UserError, match="weight_2d"):
        LossConfig(weight_2d=-1.0).validate()
    with pytest.raises(UserError, match="weight_confidence"):
        LossConfig(weight_confidence=0.0).validate()


def _pose_case(weight_pose=1.0):
    """A batch of 2 clips (3 frames) whose head outputs are exactly the true relative poses."""
    from d4rt.model.decoder import rotation_from_6d

    torch.manual_seed(0)
    b, n, t = 2, 40, 3
    c2w = torch.eye(4, dtype=torch.float64).repeat(b, t, 1, 1)
    c2w[..., :3, :3] = rotation_from_6d(torch.randn(b, t, 6, dtype=torch.float64))
    c2w[..., :3, 3] = torch.randn(b, t, 3, dtype=torch.float64)
    queries = torch.cat([torch.rand(b, n, 2), torch.randint(0, t, (b, n, 3)).float()], -1)
    clip = torch.arange(b)[:, None]
    t_src, t_cam = queries[..., 2].long(), queries[..., 4].long()
    relative = torch.linalg.inv(c2w[clip, t_cam]) @ c2w[clip, t_src]
    points = torch.randn(b, n, 3) + torch.tensor([0.0, 0.0, 4.0])
    batch = {"points": points, "uv": torch.rand(b, n, 2), "visibility": torch.ones(b, n), "motion": torch.zeros(b, n, 3),
             "normals": torch.nn.functional.normalize(torch.randn(b, n, 3), dim=-1), "valid": torch.ones(b, n, dtype=torch.bool),
             "uv_valid": torch.ones(b, n, dtype=torch.bool), "queries": queries, "cam_to_world": c2w.float()}
    pred = {"points": 2.0 * points, "uv": batch["uv"], "visibility_logit": torch.zeros(b, n), "motion": torch.zeros(b, n, 3),
            "normals": batch["normals"], "confidence": torch.ones(b, n),
            # the prediction's units are twice the target's: its translation too
            "relative_rotation": relative[..., :3, :3].float(), "relative_translation": 2.0 * relative[..., :3, 3].float()}
    return pred, batch, LossConfig(weight_pose=weight_pose), relative


def test_pose_loss_is_zero_for_the_true_relative_poses_in_any_scale():
    pred, batch, config, _ = _pose_case()
    _, terms = d4rt_loss(pred, batch, config)
    assert terms["pose_rotation"] < 1e-5 and terms["pose_translation"] < 1e-5


def test_pose_loss_counts_only_queries_that_change_camera():
    pred, batch, config, relative = _pose_case()
    moved = batch["queries"][..., 2] != batch["queries"][..., 4]
    assert 0 < int(moved.sum()) < moved.numel()
    pred["relative_translation"] = pred["relative_translation"] + torch.tensor([0.0, 0.0, 8.0])  # 2 target units
    pred["relative_translation"][moved] = 2.0 * relative[..., :3, 3][moved].float()  # right where it counts
    _, terms = d4rt_loss(pred, batch, config)
    assert terms["pose_translation"] < 1e-5
    pred["relative_translation"][moved] += torch.tensor([0.0, 0.0, 8.0])
    _, terms = d4rt_loss(pred, batch, config)
    mean_z = batch["points"][..., 2].abs().mean(1)
    assert torch.isclose(terms["pose_translation"], (4.0 / mean_z)[torch.nonzero(moved)[:, 0]].mean(), rtol=1e-4)


def test_pose_loss_off_by_default_and_refused_without_the_head():
    pred, batch, config, _ = _pose_case()
    assert "pose_rotation" not in d4rt_loss(pred, batch, LossConfig())[1]
    del pred["relative_rotation"]
    with pytest.raises(UserError, match="relative_pose_head"):
        d4rt_loss(pred, batch, config)


def test_squared_pose_translation_and_its_own_weight():
    pred, batch, _, relative = _pose_case()
    moved = batch["queries"][..., 2] != batch["queries"][..., 4]
    pred["relative_translation"][moved] += torch.tensor([0.0, 0.0, 8.0])  # 2 target units off in z
    mean_z = batch["points"][..., 2].abs().mean(1)
    per_query = (4.0 / mean_z)[torch.nonzero(moved)[:, 0]]  # the error in each side's normalised units
    plain, terms_l1 = d4rt_loss(pred, batch, LossConfig(weight_pose=1.0))
    squared = LossConfig(weight_pose=1.0, pose_translation="squared", weight_pose_translation=3.0)
    total, terms = d4rt_loss(pred, batch, squared)
    assert torch.isclose(terms["pose_translation"], per_query.square().mean(), rtol=1e-4)
    # Only the translation term changed: same rotation term, the other weight applied.
    assert torch.isclose(terms["pose_rotation"], terms_l1["pose_rotation"])
    assert torch.isclose(total - plain, 3.0 * terms["pose_translation"] - terms_l1["pose_translation"], atol=1e-5)
    with pytest.raises(UserError, match="pose_translation must be one of l1, squared"):
        LossConfig(pose_translation="l2").validate()


def test_dense_depth_term_by_hand_and_invariant_to_each_clips_scale():
    from d4rt.training.losses import dense_depth_loss

    depth = torch.tensor([[[[1.0, 2.0], [4.0, 0.0]]], [[[3.0, 3.0], [3.0, 3.0]]]])  # (B=2, T=1, 2, 2); 0: unknown
    exact = torch.log(torch.where(depth > 0, depth, torch.ones_like(depth)))
    scaled = exact + torch.tensor([5.0, -2.0]).reshape(2, 1, 1, 1)  # each clip's depth scaled by its own factor
    assert dense_depth_loss(scaled, depth).item() == pytest.approx(0.0, abs=1e-6)
    # Clip 0's known errors (0, 0, 3 * log 2) centred on their mean (log 2): |-log 2|, |-log 2|, |2 log 2|;
    # clip 1 exact: mean over the 7 known pixels.
    wrong = exact.clone()
    wrong[0, 0, 1, 0] += 3 * LOG2
    wrong[0, 0, 1, 1] += 100.0  # the unknown pixel counts for nothing
    assert dense_depth_loss(wrong, depth).item() == pytest.approx(4 * LOG2 / 7, rel=1e-6)


def test_dense_depth_term_needs_the_head_and_the_maps():
    batch = two_query_batch()
    with pytest.raises(UserError, match="weight_dense_depth needs a model with dense_depth_head"):
        d4rt_loss(perfect(batch), batch, LossConfig(weight_dense_depth=1.0))
    pred = perfect(batch) | {"dense_log_depth": torch.zeros(1, 1, 2, 2, requires_grad=True)}
    batch["depth"] = torch.tensor([[[[1.0, 2.0], [4.0, 8.0]]]])
    total, terms = d4rt_loss(pred, batch, LossConfig(weight_dense_depth=2.0))
    assert terms["dense_depth"].item() == pytest.approx(LOG2, rel=1e-6)  # |(0,1,2,3) - 1.5| log 2 on average
    total.backward()
    assert pred["dense_log_depth"].grad.abs().sum() > 0


def _camera_pair_case():
    from d4rt.data import ClipQueryDataset, DatasetConfig, QuerySamplerConfig
    from d4rt.training.data import collate_samples

    cfg = DatasetConfig(num_clips=2, frames=6, size=(32, 32), render_pixels=32 * 32,
                        sampler=QuerySamplerConfig(num_queries=300, adjacent_camera_fraction=0.3,
                                                   camera_pair_twins=True))
    dataset = ClipQueryDataset(cfg)
    return collate_samples([dataset[0], dataset[1]])


def _exact_answers(batch):
    """The batch's targets as a prediction, with confident visibility logits and unit confidence."""
    return perfect(batch) | {"visibility_logit": 30.0 * (2 * batch["visibility"] - 1),
                             "confidence": torch.ones(batch["valid"].shape)}


def test_camera_pair_term_zero_for_consistent_answers_and_prices_a_travel_error_by_its_length():
    batch = _camera_pair_case()
    config = LossConfig(weight_camera_pair=1.0)
    pred = _exact_answers(batch)
    _, terms = d4rt_loss(pred, batch, config)
    assert terms["camera_pair"] < 1e-5
    _, terms = d4rt_loss(pred | {"points": 3.0 * batch["points"]}, batch, config)  # any scale: still exact
    assert terms["camera_pair"] < 1e-5
    # Every pair's answer moved by the same vector d: each pair's travel is off by |d| / s (s the clip's mean depth).
    twin, valid = batch["twin"], batch["valid"]
    pairs = twin >= 0
    shifted = batch["points"] + torch.where(pairs[..., None], torch.tensor([0.05, 0.0, 0.0]), 0.0)
    _, terms = d4rt_loss(pred | {"points": shifted}, batch, config)
    ok = pairs & valid & torch.gather(valid, 1, twin.clamp_min(0))
    s = mean_depth(shifted, valid)
    expected = (0.05 / s[:, None]).expand_as(ok)[ok].mean()
    assert terms["camera_pair"] == pytest.approx(float(expected), rel=1e-4)
    with pytest.raises(UserError, match="camera_pair_twins: true"):
        d4rt_loss(pred, {k: v for k, v in batch.items() if k != "twin"}, config)


def test_camera_pair_direction_term_prices_the_travel_direction_not_its_length():
    batch = _camera_pair_case()
    config = LossConfig(weight_camera_pair_direction=1.0)
    pred = _exact_answers(batch)
    _, terms = d4rt_loss(pred, batch, config)
    assert terms["camera_pair_direction"] < 1e-4
    # Each pair's answer moved so that its travel doubles: the same direction, so still (almost) free.
    from d4rt.training.losses import _MIN_PAIR_TRAVEL, camera_pair_travels
    valid = batch["valid"]
    s = mean_depth(batch["points"], valid)
    _, true, paired = camera_pair_travels(batch["points"], batch["points"], valid, batch, s, s)
    moved = paired & (true.norm(dim=-1) >= _MIN_PAIR_TRAVEL)
    assert moved.sum() > 10  # the rendered clips' cameras travel
    doubled = batch["points"] + torch.where(paired[..., None], true * s[:, None, None], 0.0)
    _, terms = d4rt_loss(pred | {"points": doubled}, batch, config)
    assert terms["camera_pair_direction"] < 0.05  # the clip's mean depth moves a little with the shifted answers
    # Travels that vanish (each pair answered as its twin, rotated): 1 on every moved pair, with a finite gradient.
    twin = batch["twin"].clamp_min(0)
    from d4rt.training.losses import source_to_camera
    rotated = (source_to_camera(batch)[..., :3, :3] @ torch.gather(
        batch["points"], 1, twin[..., None].expand(-1, -1, 3))[..., None])[..., 0]
    still = torch.where(paired[..., None], rotated, batch["points"]).requires_grad_(True)
    total, terms = d4rt_loss(pred | {"points": still}, batch, config)
    assert terms["camera_pair_direction"] == pytest.approx(1.0, abs=1e-4)
    total.backward()
    assert torch.isfinite(still.grad).all() and still.grad.abs().sum() > 0
    with pytest.raises(UserError, match="camera_pair_twins: true"):
        d4rt_loss(pred, {k: v for k, v in batch.items() if k != "twin"}, config)


def on_axis_batch(z_true: torch.Tensor, times: torch.Tensor) -> dict[str, torch.Tensor]:
    """A one-clip batch of N queries at the image centre whose true points lie on the optical axis at depths
    ``z_true`` (N,), with (t_src, t_tgt, t_cam) ``times`` (N, 3); every point valid, no 2D targets."""
    n = len(z_true)
    return {"points": torch.stack([torch.zeros(n), torch.zeros(n), z_true], -1)[None],
            "queries": torch.cat([torch.full((n, 2), 0.5), times], 1)[None],
            "uv": torch.zeros(1, n, 2), "visibility": torch.zeros(1, n), "motion": torch.zeros(1, n, 3),
            "normals": torch.zeros(1, n, 3), "valid": torch.ones(1, n, dtype=torch.bool),
            "uv_valid": torch.zeros(1, n, dtype=torch.bool)}


def test_aligned_depth_term_is_the_abs_rel_of_the_depth_queries_after_the_benchmarks_alignment():
    """AbsRel of s z_pred + t against z_target over the depth queries (t_src = t_tgt = t_cam) in front of the camera,
    with z_pred over its own per-clip mean |z| and (s, t) the evaluation's L1 scale and shift; other queries, and clips
    with the depth ordered backwards, are left out; any positive scale of the prediction costs nothing more."""
    from d4rt.evaluation.metrics.depth import l1_scale_and_shift

    z_true = torch.tensor([1.0, 2.0, 4.0, 8.0, 30.0, 5.0, -3.0])
    z_pred = torch.tensor([0.6, 1.0, 2.5, 3.0, 9.0, 0.1, 2.0])
    times = torch.tensor([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3], [4, 4, 4], [0, 1, 0], [2, 2, 2]]).float()
    n = len(z_true)
    batch = on_axis_batch(z_true, times)
    pred = perfect(batch)
    pred["points"] = torch.stack([torch.zeros(n), torch.zeros(n), z_pred], -1)[None].requires_grad_()
    depth = slice(0, 5)  # query 5 changes time, query 6 lies behind the camera
    normalised = z_pred / z_pred.abs().mean()  # the prediction over its own mean |z| of every valid query
    s, t = l1_scale_and_shift(normalised[depth].double().numpy(), z_true[depth].double().numpy())
    expected = ((s * normalised[depth] + t - z_true[depth]).abs() / z_true[depth]).mean().item()
    assert expected > 0.05
    config = LossConfig(weight_aligned_depth=0.5)
    total, terms = d4rt_loss(pred, batch, config)
    assert terms["aligned_depth"].item() == pytest.approx(expected, rel=1e-4)
    without, off_terms = d4rt_loss(pred, batch, LossConfig())
    assert "aligned_depth" not in off_terms
    assert (total - without).item() == pytest.approx(0.5 * expected, rel=1e-4)
    total.backward()
    grad = pred["points"].grad[0]
    assert torch.isfinite(grad).all() and grad[depth, 2].abs().sum() > 0
    # Exactly scale-invariant, so no gradient along the prediction itself (which shrank the depth scale of a run).
    only = pred["points"].detach().clone().requires_grad_()
    aligned_only = LossConfig(weight_3d=0.0, confidence_weighting=False, weight_2d=0.0, weight_visibility=0.0,
                              weight_motion=0.0, weight_normal=0.0, weight_aligned_depth=1.0)
    d4rt_loss(perfect(batch) | {"points": only}, batch, aligned_only)[0].backward()
    radial = (only.grad * only.detach()).sum() / (only.grad.norm() * only.detach().norm())
    assert only.grad.norm() > 0 and abs(radial.item()) < 1e-5
    for scale in (1e-3, 7.0, 1e4):
        scaled = perfect(batch) | {"points": pred["points"].detach() * scale}
        assert d4rt_loss(scaled, batch, config)[1]["aligned_depth"].item() == pytest.approx(expected, rel=1e-3)
    backwards = perfect(batch) | {"points": batch["points"] * torch.tensor([1.0, 1.0, -1.0])}  # scale would be < 0
    assert d4rt_loss(backwards, batch, config)[1]["aligned_depth"].item() == 0.0
    exact = perfect(batch) | {"points": batch["points"] * torch.tensor([1.0, 1.0, 3.0]) + torch.tensor([0.0, 0.0, 1.0])}
    assert d4rt_loss(exact, batch, config)[1]["aligned_depth"].item() == pytest.approx(0.0, abs=1e-5)
    with pytest.raises(UserError, match="weight_aligned_depth must be a number >= 0"):
        LossConfig(weight_aligned_depth=-1.0).validate()


def test_aligned_depth_term_with_the_scale_alone_prices_an_affine_answer_and_not_a_proportional_one():
    """With aligned_depth_alignment "scale" the fit is the evaluation's L1 scale (shift 0): a prediction
    proportional to the truth costs nothing at any scale, an affine one costs its AbsRel after that scale."""
    from d4rt.evaluation.metrics.depth import l1_scale

    z_true = torch.tensor([1.0, 2.0, 4.0, 8.0, 30.0])
    n = len(z_true)
    batch = on_axis_batch(z_true, torch.arange(n).float()[:, None].repeat(1, 3))  # every query a depth query
    config = LossConfig(weight_aligned_depth=1.0, aligned_depth_alignment="scale")
    for scale in (0.01, 3.0):
        proportional = perfect(batch) | {"points": batch["points"] * scale}
        assert d4rt_loss(proportional, batch, config)[1]["aligned_depth"].item() == pytest.approx(0.0, abs=1e-6)
    affine_z = 3.0 * z_true + 1.0
    affine = perfect(batch) | {"points": torch.stack([torch.zeros(n), torch.zeros(n), affine_z], -1)[None]}
    normalised = affine_z / affine_z.mean()
    s = l1_scale(normalised.double().numpy(), z_true.double().numpy())
    expected = ((s * normalised - z_true).abs() / z_true).mean().item()
    assert expected > 0.05
    assert d4rt_loss(affine, batch, config)[1]["aligned_depth"].item() == pytest.approx(expected, rel=1e-4)
    shift_too = LossConfig(weight_aligned_depth=1.0)
    assert d4rt_loss(affine, batch, shift_too)[1]["aligned_depth"].item() == pytest.approx(0.0, abs=1e-5)
    with pytest.raises(UserError, match="aligned_depth_alignment must be one of scale&shift, scale"):
        LossConfig(aligned_depth_alignment="median").validate()


def test_aligned_depth_term_in_view_prices_the_queries_seen_in_their_own_frame_under_one_fit_per_clip():
    """With aligned_depth_queries "in_view" the AbsRel after the evaluation's L1 scale and shift covers every query
    with t_tgt = t_cam whose target lies in front of that camera and inside its image, whatever t_src; a query asked
    in another frame's camera, one outside the image and one behind the camera stay out."""
    from d4rt.evaluation.metrics.depth import l1_scale_and_shift

    z_true = torch.tensor([1.0, 2.0, 4.0, 8.0, 30.0, 5.0, 6.0, -3.0])
    z_pred = torch.tensor([0.6, 1.0, 2.5, 3.0, 9.0, 0.1, 7.0, 2.0])
    times = torch.tensor([[0, 0, 0], [1, 2, 2], [2, 0, 0], [3, 3, 3], [4, 1, 1], [0, 1, 0], [2, 2, 2],
                          [2, 2, 2]]).float()
    n = len(z_true)
    batch = on_axis_batch(z_true, times)
    batch["uv"] = torch.full((1, n, 2), 0.5)
    batch["uv"][0, 6] = torch.tensor([1.2, 0.5])  # in front of camera 2 but outside its image
    pred = perfect(batch) | {"points": torch.stack([torch.zeros(n), torch.zeros(n), z_pred], -1)[None]}
    priced = slice(0, 5)
    normalised = z_pred / z_pred.abs().mean()
    s, t = l1_scale_and_shift(normalised[priced].double().numpy(), z_true[priced].double().numpy())
    expected = ((s * normalised[priced] + t - z_true[priced]).abs() / z_true[priced]).mean().item()
    in_view = LossConfig(weight_aligned_depth=1.0, aligned_depth_queries="in_view")
    assert d4rt_loss(pred, batch, in_view)[1]["aligned_depth"].item() == pytest.approx(expected, rel=1e-4)
    only_depth = d4rt_loss(pred, batch, LossConfig(weight_aligned_depth=1.0))[1]["aligned_depth"].item()
    assert only_depth != pytest.approx(expected, rel=1e-2)  # queries 0 and 3 alone: another fit and mean
    with pytest.raises(UserError, match="aligned_depth_queries must be one of depth, in_view"):
        LossConfig(aligned_depth_queries="all").validate()


def test_camera_pair_rotation_term_reads_the_rotation_between_a_pairs_answers_not_their_travel():
    from d4rt.training.losses import camera_pair_rotations
    batch = _camera_pair_case()
    config = LossConfig(weight_camera_pair_rotation=1.0)
    pred = _exact_answers(batch)
    _, terms = d4rt_loss(pred, batch, config)
    assert terms["camera_pair_rotation"] < 1e-4
    valid, twin = batch["valid"], batch["twin"]
    pairs = twin >= 0
    s = mean_depth(batch["points"], valid)
    _, _, usable = camera_pair_rotations(batch["points"], batch["points"], valid, batch, s, s)
    assert usable.sum() >= 4  # the rendered pairs determine rotations
    # Every pair's answer moved by one vector (a travel error, no rotation): still free; scale-invariant too.
    shifted = batch["points"] + torch.where(pairs[..., None], torch.tensor([0.05, -0.02, 0.03]), 0.0)
    _, terms = d4rt_loss(pred | {"points": shifted}, batch, config)
    assert terms["camera_pair_rotation"] < 1e-4
    _, terms = d4rt_loss(pred | {"points": 2.5 * batch["points"]}, batch, config)
    assert terms["camera_pair_rotation"] < 1e-4
    # Every pair's answer turned by 2 degrees about the camera's y axis (its twin exact): the rigid fit between the two
    # answers is off by that rotation, which the term reads (linearised: to a few percent).
    angle = math.radians(2.0)
    turn = torch.tensor([[math.cos(angle), 0.0, math.sin(angle)], [0.0, 1.0, 0.0],
                         [-math.sin(angle), 0.0, math.cos(angle)]])
    turned = torch.where(pairs[..., None], batch["points"] @ turn.T, batch["points"]).requires_grad_(True)
    total, terms = d4rt_loss(pred | {"points": turned}, batch, config)
    assert terms["camera_pair_rotation"].item() == pytest.approx(angle, rel=0.05)
    total.backward()
    assert torch.isfinite(turned.grad).all() and turned.grad.abs().sum() > 0
    with pytest.raises(UserError, match="camera_pair_twins: true"):
        d4rt_loss(pred, {k: v for k, v in batch.items() if k != "twin"}, config)
    with pytest.raises(UserError, match="weight_camera_pair_rotation must be a number >= 0"):
        LossConfig(weight_camera_pair_rotation=-1.0).validate()


def test_body_relative_depth_term_prices_the_depth_ratio_across_bodies_in_one_frame_only():
    """The mean |log(z_i / z_j) - log(z*_i / z*_j)| over the in-view pairs of one frame on different bodies: pairs
    within one body, across frames, asked in another frame's camera or outside the image stay out; any scale of the
    prediction costs nothing; a frame read uniformly nearer costs nothing, a body read nearer than its background
    does."""
    z_true = torch.tensor([2.0, 10.0, 12.0, 3.0, 20.0, 5.0, 4.0, 6.0])
    z_pred = torch.tensor([1.0, 10.0, 12.0, 3.0, 20.0, 1.0, 1.0, 1.0])
    #                      body 1 vs env 0 (frame 0) | frame 1: body 2, env | out: t_cam != t_tgt, outside, frame 2
    times = torch.tensor([[0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 1], [0, 1, 1], [0, 0, 1], [0, 0, 0],
                          [2, 2, 2]]).float()
    n = len(z_true)
    batch = on_axis_batch(z_true, times)
    batch["uv"] = torch.full((1, n, 2), 0.5)
    batch["uv"][0, 6] = torch.tensor([0.5, -0.1])  # in front of camera 0 but outside its image
    batch["object_id"] = torch.tensor([[1, 0, 0, 2, 0, 1, 1, 0]])
    pred = perfect(batch) | {"points": torch.stack([torch.zeros(n), torch.zeros(n), z_pred], -1)[None]}
    pred["points"].requires_grad_()
    # Frame 0: query 0 (body 1) against 1 and 2 (environment); frame 1: query 3 (body 2) against 4. Query 0 is read
    # at half its depth against its background: each of its pairs costs log 2; frame 1 is exact.
    expected = (2 * LOG2 + 0.0) / 3
    config = LossConfig(weight_body_relative_depth=0.5)
    total, terms = d4rt_loss(pred, batch, config)
    assert terms["body_relative_depth"].item() == pytest.approx(expected, rel=1e-5)
    without, off_terms = d4rt_loss(pred, batch, LossConfig())
    assert "body_relative_depth" not in off_terms
    assert (total - without).item() == pytest.approx(0.5 * expected, rel=1e-4)
    total.backward()
    grad = pred["points"].grad[0, :, 2]
    assert torch.isfinite(grad).all() and grad[0] < 0 and grad[1:3].sum() > 0  # body pushed back, background nearer
    for scale in (1e-3, 7.0, 1e4):
        scaled = perfect(batch) | {"points": pred["points"].detach() * scale}
        assert d4rt_loss(scaled, batch, config)[1]["body_relative_depth"].item() == pytest.approx(expected, rel=1e-4)
    nearer = z_true.clone()
    nearer[:3] = nearer[:3] / 3  # all of frame 0 read three times nearer: every ratio in it kept
    uniform = perfect(batch) | {"points": torch.stack([torch.zeros(n), torch.zeros(n), nearer], -1)[None]}
    assert d4rt_loss(uniform, batch, config)[1]["body_relative_depth"].item() == pytest.approx(0.0, abs=1e-6)
    one_body = batch | {"object_id": torch.zeros(1, n, dtype=torch.long)}
    lone = d4rt_loss(pred, one_body, config)[1]["body_relative_depth"]
    assert lone.item() == 0.0
    with pytest.raises(UserError, match="weight_body_relative_depth needs batches with object_id"):
        d4rt_loss(pred, {k: v for k, v in batch.items() if k != "object_id"}, config)
    with pytest.raises(UserError, match="weight_body_relative_depth must be a number >= 0"):
        LossConfig(weight_body_relative_depth=-1.0).validate()
