"""The paper's training losses (App. A), each masked to the queries whose ground truth exists.

    L = c * L3D - w_conf * log(c) + w_2d * L2D + w_vis * Lvis + w_motion * Lmotion + w_normal * Lnormal

with default weights 1 / 0.2 / 0.1 / 0.1 / 0.1 / 0.5. Every term is a mean over the queries where it is
defined (pooled over the clips of the batch), so a batch with many missing targets does not shrink the
loss.

Which ground truth each term needs (``valid`` and ``uv_valid`` come from the dataset, see
:func:`d4rt.data.make_training_sample`):

======================  =============  =====================================================================
term                    mask           why
======================  =============  =====================================================================
L3D, confidence         ``valid``      the query pixel has a true 3D point (real data's sky has none; the
                                       synthetic sky dome has one, and is supervised)
motion                  ``valid``      defined for every existing surface point, in camera t_cam
normals                 ``valid``      and ``normals_valid`` when the batch has it (track data has no normals)
visibility              ``valid``      a point behind camera t_tgt or outside its image is simply *not
                                       visible*: target 0 is ground truth, so it is supervised
L2D                     ``uv_valid``   the projection into frame t_tgt only exists in front of that camera;
                                       behind it (z <= 0) there is no 2D position to regress. In front of
                                       the camera but outside the image it is still supervised (the head
                                       may leave [0, 1]); L1 keeps the gradient bounded for far projections
======================  =============  =====================================================================

Choices the paper leaves open (documented in docs/training.md, configurable in :class:`LossConfig`):

- *Per-clip mean depth.* The 3D targets of one clip live in different cameras t_cam. We normalise each
  clip's points by ONE scalar: the mean of ``|z|`` over the clip's valid queries, each ``z`` taken in the
  query's own camera t_cam, computed separately for the prediction and for the target. One scalar per clip
  (not per camera) because all cameras of a clip share one scale: per-camera factors would let the
  prediction scale each camera differently and break the cross-view consistency that camera poses are
  fitted from. ``|z|`` (not ``z``) so that points behind camera t_cam, which exist when t_cam != t_tgt,
  add to the scale instead of cancelling it.
- *L1* is the L1 norm of the error vector (sum over its coordinates), then the mean over queries.
- *Motion* is compared in the same normalised units as the points (prediction divided by the
  prediction's scale, target by the target's), so that ``points(t_tgt) - points(t_src) = motion`` holds
  in the model's own scale. The prediction's scale is detached there: the free overall scale of the
  points is fixed by L3D alone. ``normalise_motion=False`` compares raw vectors.
- *Normals*: ``1 - cos(pred, target)``. *Visibility*: binary cross-entropy on the model's logit.
- *Pose* (not in paper; ``weight_pose`` > 0, only for a model with ``relative_pose_head``): the head's
  rotation and translation from camera t_src to camera t_cam against the true ones from the batch's
  ``cam_to_world``, on every query with t_cam != t_src: L1 over the 9 rotation-matrix entries plus L1 of
  the translation, each translation divided by its own side's per-clip mean depth (the prediction's
  detached, as for motion). Why: every tiny model trained on the paper's losses alone ignored t_cam; the
  points loss mixes a query's camera motion with its depth error, this term names the motion directly.
  ``pose_translation="squared"`` compares the translations by the squared error instead, weighted by
  ``weight_pose_translation`` (default: ``weight_pose``). Why: under L1 every query pushes with the same
  force whatever its true translation, so the many clips whose camera barely travels (pans, a camera
  held still) outvote the few whose parallax shows the direction of travel, and the head stays at zero
  translation (stage 10, docs/training.md); the squared error's push grows with the true translation.
- *Camera pair* (not in paper; ``weight_camera_pair`` > 0, batches from a sampler with ``camera_pair_twins``):
  for each camera-pair query (the point of pixel (u, v) of frame t_src at time t_src, seen in camera
  t_cam = t_src +- 1) and its twin (the same point in camera t_src), the travel the two answers imply,
  ``P_pair - R P_twin`` with the true rotation R from camera t_src to camera t_cam, against the true
  travel, each side divided by its own per-clip mean depth (the prediction's detached), as the Euclidean
  length of the difference. Why: the chained camera path (``pose_pairs="adjacent"``) fits each step from
  exactly these two answers, and the step's travel came out nearly unrelated to the true direction (median
  cosine 0.1-0.2, stage 76, docs/training.md): L3D prices each answer's error alone, so errors that differ
  between the two cameras cost it nothing extra, though they are all the chain sees. The length (not its
  square) pushes every pair with the same force, however short its step (stage 10's lesson for the pose
  head). Stage 86.
- *Camera-pair direction* (not in paper; ``weight_camera_pair_direction`` > 0, the same pairs): the distance
  between the unit direction of the true travel and the predicted travel divided by its length, the length floored
  at ``_MIN_PAIR_TRAVEL_LENGTH`` (both in units of each side's per-clip mean depth), on the pairs whose true travel is
  at least ``_MIN_PAIR_TRAVEL`` (a camera turning on the spot has no direction to learn, and a step's direction moves
  the chained path by its length). Why: the shipped chain's step translations pointed 83-92% along the optical axis
  (median cosine 0.16-0.32 with the true step), and the camera-pair term prices a travel's error by its length, so
  the direction of the many short steps cost it almost nothing. The floor keeps the gradient finite where the
  predicted travel vanishes (there the term is 1 and pushes it out along the truth). Stage 120 (docs/training.md):
  it turned the steps (median cosine 0.21 -> 0.59) and the chained path got worse; not in any shipped recipe.
- *Camera-pair rotation* (not in paper; ``weight_camera_pair_rotation`` > 0, the same pairs): per clip and camera
  pair (t_src, t_cam), the small rotation (radians) that best explains, by least squares, how the pairs' predicted
  travels vary with where their twins lie (each side centred on the group's mean), ``omega`` solving
  ``sum (|d|^2 I - d d^T) omega = sum d x r`` with d the twin's answer turned by the true rotation and r the travel,
  both in units of the prediction's mean depth; the same for the target (0 for exact answers: a rigid motion moves
  every point of a pair by one travel); the term is the mean over the groups of ``|omega_pred - omega_target|``. It is
  the rotation error of the rigid fit the camera recipe makes from those answers, linearised. Groups with fewer than
  three pairs or whose twins lie nearly on a line (the smallest eigenvalue of the matrix per pair below
  ``_MIN_PAIR_SPREAD``) are left out. Why: the camera-pair term prices each pair's travel under the TRUE rotation,
  so the rotation the answers encode between two cameras is never priced, and on held-out clips the chained
  one-frame fits' rotation was as far from the truth as no rotation at all; with the true rotation and each step's
  translation refitted under it, the start's held-out ATE fell 0.0349 -> 0.0313 and the in-view weights' 0.0482 ->
  0.0364 (stage 125, docs/training.md). Not yet trained in any stage.
- *Log depth* (not in paper; ``weight_log_depth`` > 0): ``|log(z_pred / s_pred) - log(z_target / s_target)|``
  on the queries whose target lies in front of camera t_cam, each side divided by its own per-clip mean
  depth ``s`` (as L3D, so the term is scale-invariant). Why: L3D's log-compressed coordinates weigh the ratio
  of far to near depth weakly (a sky predicted 6x too near and near ground 2x too far cost L3D less than 1
  per query), while a depth map's relative error (AbsRel, after one alignment per sequence) is decided by
  that ratio; the log depth costs a ratio's error the same at every depth. A prediction below
  ``_MIN_LOG_DEPTH`` of its clip's mean depth (or behind the camera) gets no gradient from this term; L3D
  still pulls it.
- *Aligned depth* (not in paper; ``weight_aligned_depth`` > 0): the benchmark's own depth error as a term. Over each
  clip's depth queries (t_src = t_tgt = t_cam) whose target lies in front of the camera, the predicted z is aligned to
  the true z by the L1-optimal scale and shift of the video-depth protocol (``l1_scale_and_shift``, the evaluation's
  own solver, on detached values), then each query costs ``|s z_pred + t - z_target| / z_target`` (AbsRel). Why: the
  benchmark aligns one scale and shift per sequence by L1 in metres, so the far pixels (tens of metres) set it and a
  far range squeezed against the near one throws every near pixel's relative error up (a few outdoor clips decide
  the pooled AbsRel, docs/training.md); L3D and the log-depth term price near and far in their own normalised or log
  units and never see that alignment. The prediction is divided by its own per-clip mean depth first (as in L3D),
  so the term is exactly invariant to the prediction's scale. A clip whose fitted scale is not positive (depth
  ordered backwards) or with fewer than two such queries is left to the other terms. With
  ``aligned_depth_alignment: scale`` the fit is the L1-optimal scale alone (``l1_scale``): the answers are then
  priced as proportional to the truth, where the protocol's shift lets them drift to merely affine. Measured (stage
  96, weight 1.0 against a control): held-out L3D +0.20, several times the scale-and-shift term's cost (+0.056).
  With ``aligned_depth_queries: in_view`` every query with t_tgt = t_cam whose target lies in front of that camera
  and inside its image (the depth some frame's depth map holds there, were the point not hidden) is priced, under
  one fit per clip (all cameras of a clip share one scale, as for L3D). Why: a uniform draw makes about 2% of the
  queries depth queries, some 20 per clip, so the term rarely lands on a body near the camera, the pixels that
  decide the worst clips (stage 112, docs/training.md); the same error divided by the true z weighs those near points
  most. Not every query: a point outside camera t_cam's view can lie just in front of its image plane, where the
  division by its true z blows the error up (the term over all in-front queries ran twice the depth queries' on the
  same batches, measured before stage 114).
- *Body-relative depth* (not in paper; ``weight_body_relative_depth`` > 0, batches with ``object_id``): over each
  pair of queries of one clip seen in the same frame (both with t_tgt = t_cam, in front of that camera and inside its
  image, the in-view queries of the aligned-depth term) whose points lie on different rigid bodies (the static
  environment is body 0), the error of the log depth ratio: ``|log(z_i / z_j) - log(z*_i / z*_j)|``, averaged over
  the pairs. Why: stages 132-133 weighed near bodies more (more queries on them, the aligned-depth term's AbsRel) and
  the model read whole frames nearer instead of telling a near body from the background behind it: the worst clips
  gained, delta<1.25 lost on nearly every clip and the far/near error rose (docs/training.md). A ratio between two
  things in one frame is free of any scale, so the term prices only where a body stands against its background and
  leaves the far range (pairs within the environment) to the other terms. A prediction below ``_MIN_LOG_DEPTH`` of
  its clip's mean depth (or behind the camera) gets no gradient from it.
- *Dense depth* (not in paper; ``weight_dense_depth`` > 0, only for a model with ``dense_depth_head``): the
  head's log-depth of every input pixel against the log of the batch's ``depth`` maps, over the pixels with
  a true depth, each clip's errors centred on their clip mean before the L1: ``|e - mean_clip(e)|`` with
  ``e = pred - log(z)``, invariant to a per-clip scale of depth. Why: a depth query is ~2% of the ~1,000
  queries a clip is asked, while this term supervises every pixel of every frame through the scene tokens
  the queries read (stage 67, docs/training.md); the queries still answer every output.
- *Correspondence attention* (not in paper; ``weight_correspondence`` > 0): the cross-entropy between the
  first head's attention of decoder block ``correspondence_block`` and where the query's point lies at t_tgt:
  the scene tokens of t_tgt's time step around the true (u, v) in frame t_tgt, weighted bilinearly over the
  four token centres nearest it. Over the queries whose point is visible in frame t_tgt (in front, inside the
  image, not occluded). Why: the trained tiny models' decoders spread their attention over every time step
  alike (the mass on t_tgt's step equals the uniform share in every block and head, stage 79,
  docs/training.md), so no query reads the frame it is asked about, and their tracks hardly move (a point's
  predicted displacement 0.05 of the image where it truly moves 0.29, at a 20-frame gap). The term tells one head where to
  look; the answers still come from L3D and L2D, and inference is unchanged. Measured (stages 79-81, 1,200 steps
  from the shipped weights): the head learns the image position, and the frame when pushed, but not the point's new
  position, and the 2D answers did not improve; off in every shipped config.
- *Ray angle* (not in paper; ``weight_ray_angle`` > 0): the angle between the predicted and the true point
  as seen from camera t_cam (the angle between the two vectors, whatever their lengths), divided by the
  clip's mean angle of its true in-front points off the optical axis (a stand-in for half the field of
  view). Why: a focal error moves every point sideways by a fixed share of its angle off the axis, and L3D
  prices that sideways error in the points' own units: in a 30-degree view a 40% focal error moves points
  by about 5% of their depth, less than the depth error L3D is busy with, so narrow views' focal stays
  pulled toward the mean field of view (stage 50, docs/training.md). Divided by the clip's own angular
  spread, the same focal error costs the same at every field of view; the angle ignores depth, so the
  term does not compete with L3D over it. ``ray_angle_spread="geometric"`` divides by the geometric mean of
  the true and the predicted spread instead. Why: over the true spread alone, angles read k times too wide
  cost a clip about ``|k - 1|``, so reading a view twice too wide (focal halved) costs 1 and twice too narrow
  0.5; a model unsure of the field of view then hedges narrow, its focal long (at weight 2, stages 52-53 read
  every focal 7-14% longer than stage 51 at weight 1, docs/training.md). Over both spreads the cost is
  ``|k - 1| / sqrt(k) = 2 sinh(|log k| / 2)``, the same for k and 1 / k.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from d4rt.errors import UserError
from d4rt.evaluation.metrics.depth import l1_scale, l1_scale_and_shift
from d4rt.geometry.transforms import invert_rigid

# Prediction and batch keys the loss reads.
PREDICTION_KEYS = ("points", "uv", "visibility_logit", "motion", "normals", "confidence")
# How the pose loss compares translations (LossConfig.pose_translation).
POSE_TRANSLATION_ERRORS = ("l1", "squared")
# What the ray-angle term divides by (LossConfig.ray_angle_spread).
RAY_ANGLE_SPREADS = ("target", "geometric")
# What the aligned-depth term fits per clip (LossConfig.aligned_depth_alignment).
ALIGNED_DEPTH_ALIGNMENTS = ("scale&shift", "scale")
# Which queries the aligned-depth term prices (LossConfig.aligned_depth_queries).
ALIGNED_DEPTH_QUERIES = ("depth", "in_view")
# Guards a degenerate all-zero prediction only; real scenes are many orders of magnitude deeper.
_MIN_SCALE = 1e-12
# Lowest normalised depth the log-depth term takes a log of (1/1000 of the clip's mean depth).
_MIN_LOG_DEPTH = 1e-3
# Smallest per-clip angular spread (radians) the ray-angle term divides by: a clip seen head-on along
# one ray only (never in real data) cannot blow the term up.
_MIN_RAY_SPREAD = 1e-3
# The camera-pair direction term: the shortest true travel (in mean depths) whose direction it prices (about the
# shortest quarter of the rendered pairs' steps are shorter: their direction hardly moves the chained path), and the
# length below which a predicted travel's direction is priced as if it were that long.
_MIN_PAIR_TRAVEL = 1e-2
_MIN_PAIR_TRAVEL_LENGTH = 1e-2
# The camera-pair rotation term: the smallest eigenvalue of a group's lever-arm matrix per pair (in squared mean
# depths) it fits a rotation from; below it the twins lie nearly on a line or a point and the rotation about that
# line is undetermined (a 64-pixel frame's points spread over tenths of the mean depth: eigenvalues ~1e-2).
_MIN_PAIR_SPREAD = 1e-4


@dataclass
class LossConfig:
    """Weights of the loss terms (paper defaults) and the open choices described in the module docstring.

    confidence_weighting: multiply L3D by the predicted confidence c and add ``-w_conf * log(c)``
        (Kendall & Gal). False trains plain L3D (the paper's "no confidence" ablation).
    confidence_stop_gradient: (not in paper; needs confidence_weighting) the confidence learns exactly as
        above, from ``c * L3D`` with L3D detached, while the points learn from plain L3D. Why: at the
        confidence's optimum c = w_conf / L3D, so ``c * L3D`` gives each query's points a gradient scaled
        by 1 / L3D: the hardest queries (far sky, whose depth then decides a sequence's L1 depth alignment)
        learn least. The confidence keeps its meaning (it still ranks queries by their expected error).
    weight_log_depth: (not in paper) weight of the scale-invariant log-depth term (module docstring); 0 = off.
    weight_aligned_depth: (not in paper) weight of the aligned-depth (AbsRel) term on the depth queries (module
        docstring); 0 = off.
    weight_body_relative_depth: (not in paper) weight of the body-relative depth term (module docstring); 0 = off.
        Needs batches with ``object_id`` (rendered clips; not per-point track datasets).
    aligned_depth_alignment: (not in paper) the alignment that term fits per clip: "scale&shift" (the video-depth
        protocol's, as the benchmark) or "scale" (the L1-optimal scale alone, so the answers are priced as
        proportional to the truth rather than merely affine to it; it cost the 3D points more, stage 96).
    aligned_depth_queries: (not in paper) which queries that term prices: "depth", the depth queries
        (t_src = t_tgt = t_cam, about 2% of a uniform draw), or "in_view", every query with t_tgt = t_cam whose
        target lies in front of that camera and inside its image, under one fit per clip (module docstring; stage
        114).
    weight_dense_depth: (not in paper) weight of the dense depth term (module docstring); 0 = off. Needs a
        model with ``dense_depth_head`` and batches with ``depth`` maps.
    weight_correspondence: (not in paper) weight of the correspondence-attention term (module docstring);
        0 = off. The model is then asked for ``attention_log_probs`` of decoder block ``correspondence_block``
        (:attr:`attention_block`).
    ray_angle_spread: (not in paper) what the ray-angle term divides each clip's angles by: "target", its
        true points' mean angle off the axis, or "geometric", the geometric mean of that and the
        prediction's (module docstring).
    """

    weight_3d: float = 1.0
    weight_confidence: float = 0.2
    weight_2d: float = 0.1
    weight_visibility: float = 0.1
    weight_motion: float = 0.1
    weight_normal: float = 0.5
    confidence_weighting: bool = True
    confidence_stop_gradient: bool = False
    normalise_motion: bool = True
    weight_pose: float = 0.0
    pose_translation: str = "l1"
    weight_pose_translation: float | None = None
    weight_camera_pair: float = 0.0
    weight_camera_pair_direction: float = 0.0
    weight_camera_pair_rotation: float = 0.0
    weight_log_depth: float = 0.0
    weight_aligned_depth: float = 0.0
    weight_body_relative_depth: float = 0.0
    aligned_depth_alignment: str = "scale&shift"
    aligned_depth_queries: str = "depth"
    weight_ray_angle: float = 0.0
    ray_angle_spread: str = "target"
    weight_dense_depth: float = 0.0
    weight_correspondence: float = 0.0
    correspondence_block: int = 0

    @property
    def attention_block(self) -> int | None:
        """The decoder block whose attention the loss needs (the model's ``attention_block``), or None."""
        return self.correspondence_block if self.weight_correspondence > 0 else None

    def validate(self) -> None:
        optional = ("weight_pose_translation",) if self.weight_pose_translation is not None else ()
        for name in ("weight_3d", "weight_confidence", "weight_2d", "weight_visibility", "weight_motion",
                     "weight_normal", "weight_pose", "weight_camera_pair", "weight_camera_pair_direction",
                     "weight_camera_pair_rotation", "weight_log_depth", "weight_aligned_depth", "weight_body_relative_depth",
                     "weight_ray_angle", "weight_dense_depth", "weight_correspondence", *optional):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                raise UserError(f"loss {name} must be a number >= 0, got {value!r}")
        if self.pose_translation not in POSE_TRANSLATION_ERRORS:
            raise UserError(f"loss pose_translation must be one of {', '.join(POSE_TRANSLATION_ERRORS)}, "
                            f"got {self.pose_translation!r}")
        if self.aligned_depth_alignment not in ALIGNED_DEPTH_ALIGNMENTS:
            raise UserError(f"loss aligned_depth_alignment must be one of {', '.join(ALIGNED_DEPTH_ALIGNMENTS)}, "
                            f"got {self.aligned_depth_alignment!r}")
        if self.aligned_depth_queries not in ALIGNED_DEPTH_QUERIES:
            raise UserError(f"loss aligned_depth_queries must be one of {', '.join(ALIGNED_DEPTH_QUERIES)}, "
                            f"got {self.aligned_depth_queries!r}")
        if self.ray_angle_spread not in RAY_ANGLE_SPREADS:
            raise UserError(f"loss ray_angle_spread must be one of {', '.join(RAY_ANGLE_SPREADS)}, "
                            f"got {self.ray_angle_spread!r}")
        if not isinstance(self.correspondence_block, int) or self.correspondence_block < 0:
            raise UserError(f"loss correspondence_block must be an integer >= 0, got {self.correspondence_block!r}")
        if self.confidence_stop_gradient and not self.confidence_weighting:
            raise UserError("loss confidence_stop_gradient needs confidence_weighting (there is no confidence term)")
        if self.confidence_weighting and self.weight_confidence <= 0:
            raise UserError("loss weight_confidence must be > 0 with confidence_weighting (else c collapses to 0)")


def log_compress(x: torch.Tensor) -> torch.Tensor:
    """``sign(x) * log(1 + |x|)``, elementwise: tames far points while keeping near ones linear."""
    return torch.sign(x) * torch.log1p(x.abs())


def mean_depth(points: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-clip mean of ``|z|`` over the masked queries.

    points: (B, N, 3) in each query's camera t_cam; mask: (B, N) bool. Returns (B,), at least a tiny
    positive number (a clip without any valid query gets that minimum; its queries are masked anyway).
    """
    return masked_mean_per_clip(points[..., 2].abs(), mask).clamp_min(_MIN_SCALE)


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of ``values`` (B, N) over ``mask`` (B, N) bool; 0 (still attached to the graph) if empty.
    ``where`` instead of a product so that a non-finite value under the mask cannot leak in."""
    picked = torch.where(mask, values, torch.zeros_like(values))
    return picked.sum() / mask.sum().clamp_min(1)


def point_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-query L3D: (B, N). Both point sets are divided by their own per-clip mean depth, log-compressed,
    and compared with the L1 norm. Invariant to a positive scale of either set."""
    pred_n = pred / mean_depth(pred, mask)[:, None, None]
    target_n = target / mean_depth(target, mask)[:, None, None]
    return (log_compress(pred_n) - log_compress(target_n)).abs().sum(-1)


def log_depth_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-query scale-invariant log-depth error (module docstring) and where it is defined.

    pred, target: (B, N, 3) in each query's camera t_cam; mask: (B, N) bool (queries with a true point).
    Returns ``(error (B, N), in_front (B, N) bool)``: ``in_front`` is ``mask`` where the target's z > 0.
    """
    in_front = mask & (target[..., 2] > 0)
    pred_z = pred[..., 2] / mean_depth(pred, mask)[:, None]
    target_z = target[..., 2] / mean_depth(target, mask)[:, None]
    error = torch.log(pred_z.clamp_min(_MIN_LOG_DEPTH)) - torch.log(target_z.clamp_min(_MIN_LOG_DEPTH))
    return error.abs(), in_front


def aligned_depth_loss(pred: torch.Tensor, target: torch.Tensor, queries: torch.Tensor, mask: torch.Tensor,
                       alignment: str = "scale&shift", which: str = "depth", target_uv: torch.Tensor | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-query AbsRel of the priced queries (``which``) after each clip's L1 alignment (module docstring).

    ``alignment`` is "scale&shift" (the benchmark's: :func:`l1_scale_and_shift`) or "scale" (:func:`l1_scale`, shift
    0). ``which`` is "depth" (the depth queries) or "in_view" (the queries with t_tgt = t_cam whose ``target_uv``,
    (B, N, 2) the true (u, v) in frame t_tgt, lies inside the image).

    pred, target: (B, N, 3) in each query's camera t_cam; queries: (B, N, 5) (u, v, t_src, t_tgt, t_cam); mask: (B, N)
    bool (queries with a true point). Returns ``(error (B, N), used (B, N) bool)``: ``used`` marks the priced queries
    with a target in front of the camera, in the clips whose alignment exists (at least two of them, positive scale).
    The prediction is first divided by its own per-clip mean depth (:func:`mean_depth` over ``mask``, with its
    gradient, as L3D does); the scale and shift fitted to that are constants of the step. Why the division: with the
    raw prediction the detached alignment's gradient has a component along the prediction itself, which shrank the
    model's depth scale 10-20 times in 600 steps (stage 93's first arm) and grew every scale-invariant term's
    gradient as much; divided by its own mean the term is exactly invariant to the prediction's scale.
    """
    if which == "depth":
        times = queries[..., 2:5]
        used = mask & (target[..., 2] > 0) & (times[..., 0] == times[..., 1]) & (times[..., 1] == times[..., 2])
    else:
        if target_uv is None:
            raise ValueError("aligned_depth_loss with which='in_view' needs target_uv (the batch's uv)")
        used = in_view_queries(target, queries, mask, target_uv)
    pred_z, target_z = pred[..., 2] / mean_depth(pred, mask)[:, None], target[..., 2]
    scale, shift = torch.zeros(pred.shape[0], dtype=pred.dtype), torch.zeros(pred.shape[0], dtype=pred.dtype)
    for b in range(pred.shape[0]):
        picked = used[b]
        if int(picked.sum()) >= 2:
            p, g = (z[b, picked].detach().double().cpu().numpy() for z in (pred_z, target_z))
            scale[b], shift[b] = l1_scale_and_shift(p, g, rel_tol=1e-6) if alignment == "scale&shift" else (
                l1_scale(p, g), 0.0)
    used = used & (scale > 0).to(used.device)[:, None]
    scale, shift = scale.to(pred.device), shift.to(pred.device)
    safe_target = torch.where(used, target_z, torch.ones_like(target_z))
    error = (scale[:, None] * pred_z + shift[:, None] - safe_target).abs() / safe_target
    return error, used


def in_view_queries(target: torch.Tensor, queries: torch.Tensor, mask: torch.Tensor, target_uv: torch.Tensor
                    ) -> torch.Tensor:
    """The queries seen in their own frame: t_tgt = t_cam, the target in front of that camera and inside its image.

    target: (B, N, 3) in each query's camera t_cam; queries: (B, N, 5); mask: (B, N) bool (queries with a true point);
    target_uv: (B, N, 2), the true (u, v) in frame t_tgt. Returns (B, N) bool.
    """
    times = queries[..., 2:5]
    return (mask & (target[..., 2] > 0) & (times[..., 1] == times[..., 2])
            & ((target_uv >= 0) & (target_uv <= 1)).all(-1))


def body_relative_depth_loss(pred: torch.Tensor, target: torch.Tensor, queries: torch.Tensor, mask: torch.Tensor,
                             target_uv: torch.Tensor, object_id: torch.Tensor) -> torch.Tensor:
    """The body-relative depth term (module docstring): the mean log-ratio error over the pairs of in-view queries
    (:func:`in_view_queries`) of one clip and one frame whose points lie on different bodies.

    pred, target: (B, N, 3) in each query's camera t_cam; queries: (B, N, 5); mask: (B, N) bool; target_uv: (B, N, 2);
    object_id: (B, N) long. Returns a scalar: 0 (still attached to the graph) when no such pair exists. The pairs are
    formed densely, N^2 per clip (4 MiB of float32 per clip at 1,024 queries).
    """
    used = in_view_queries(target, queries, mask, target_uv)
    pred_z = (pred[..., 2] / mean_depth(pred, mask)[:, None]).clamp_min(_MIN_LOG_DEPTH)
    safe_target = torch.where(used, target[..., 2], torch.ones_like(target[..., 2]))
    error = torch.log(pred_z) - torch.log(safe_target)  # (B, N): the log ratio's error is error_i - error_j
    frame = queries[..., 4]
    pairs = (used[:, :, None] & used[:, None, :] & (frame[:, :, None] == frame[:, None, :])
             & (object_id[:, :, None] != object_id[:, None, :]))  # (B, N, N), each pair twice
    differences = (error[:, :, None] - error[:, None, :]).abs()
    return torch.where(pairs, differences, torch.zeros_like(differences)).sum() / pairs.sum().clamp_min(1)


def dense_depth_loss(pred_log_depth: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """The dense depth term (module docstring): a scalar, the mean over the clips' pixels with a true depth.

    pred_log_depth: (B, T, H, W) log-depth up to a per-clip constant; depth: (B, T, H, W) true z-depth, 0 where
    unknown. A batch without any true depth gives 0 (still attached to the graph).
    """
    known = depth > 0
    error = pred_log_depth.float() - torch.log(torch.where(known, depth, torch.ones_like(depth)))
    flat_error, flat_known = error.flatten(1), known.flatten(1)
    centred = flat_error - masked_mean_per_clip(flat_error, flat_known)[:, None]
    return masked_mean(centred.abs(), flat_known)


def correspondence_targets(queries: torch.Tensor, uv: torch.Tensor, token_grid: torch.Tensor
                           ) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each query's point lies among the scene tokens: the four tokens of t_tgt's time step whose centres
    surround the true (u, v) in frame t_tgt, and their bilinear weights (summing to 1; a point within half a
    token of the border puts the share of the missing neighbours on the border tokens).

    queries: (B, N, 5) [u, v, t_src, t_tgt, t_cam]; uv: (B, N, 2) true (u, v) in frame t_tgt, in [0, 1];
    token_grid: (4,) time steps, rows, columns, frames per step (the model's ``token_grid``).
    Returns ``(index (B, N, 4) long, weight (B, N, 4))``: token indices in (time step, row, column) order.
    """
    _, rows, cols, per_step = (int(v) for v in token_grid)
    step = queries[..., 3].round().long() // per_step
    x = uv[..., 0].float() * cols - 0.5  # token centres at integers
    y = uv[..., 1].float() * rows - 0.5
    x0, y0 = x.floor(), y.floor()
    fx, fy = x - x0, y - y0
    index, weight = [], []
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            row = (y0 + dy).clamp(0, rows - 1).long()
            col = (x0 + dx).clamp(0, cols - 1).long()
            index.append((step * rows + row) * cols + col)
            weight.append(wy * wx)
    return torch.stack(index, -1), torch.stack(weight, -1)


def correspondence_loss(log_probs: torch.Tensor, token_grid: torch.Tensor, batch: dict[str, torch.Tensor]
                        ) -> torch.Tensor:
    """The correspondence-attention term (module docstring): a scalar.

    log_probs: (B, N, M) a head's log attention over the scene tokens; token_grid: (4,) as
    :func:`correspondence_targets`; batch: ``queries``, ``uv``, ``visibility``, ``valid``, ``uv_valid``.
    A batch without any visible query gives 0 (still attached to the graph).
    """
    uv = batch["uv"].float()
    seen = (batch["valid"].bool() & batch["uv_valid"].bool() & (batch["visibility"] > 0.5)
            & ((uv >= 0) & (uv <= 1)).all(-1))
    index, weight = correspondence_targets(batch["queries"], torch.where(seen[..., None], uv, 0.5), token_grid)
    cross_entropy = -(weight * log_probs.float().gather(-1, index)).sum(-1)
    return masked_mean(cross_entropy, seen)


def vector_angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle in radians between the vectors ``a`` and ``b`` (..., 3), elementwise: (...). ``atan2`` of the
    cross and dot products stays exact near 0 and pi, where ``acos`` of a cosine loses its precision."""
    cross = torch.linalg.cross(a, b, dim=-1)
    return torch.atan2(torch.linalg.vector_norm(cross, dim=-1), (a * b).sum(-1))


def ray_angle_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, spread: str = "target"
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-query ray-angle error (module docstring) and where it is defined.

    pred, target: (B, N, 3) in each query's camera t_cam; mask: (B, N) bool (queries with a true point).
    Returns ``(error (B, N), defined (B, N) bool)``: the angle between ``pred`` and ``target`` divided by the
    clip's mean angle off the optical axis of its targets in front of camera t_cam (``spread="target"``), or
    by the geometric mean of that and the same queries' predicted mean angle (``"geometric"``); ``defined``
    is ``mask`` where neither point is at the camera centre.
    """
    defined = mask & (target.norm(dim=-1) > 0) & (pred.detach().norm(dim=-1) > 0)
    axis = torch.zeros_like(target)
    axis[..., 2] = 1.0
    # Zero vectors (targets zeroed where missing; a degenerate prediction) are swapped for the axis:
    # atan2(0, 0)'s gradient is NaN, and a NaN times the zero gradient of a masked-out query is still NaN.
    target = torch.where(defined[..., None], target, axis)
    pred = torch.where(defined[..., None], pred, axis)
    in_front = defined & (target[..., 2] > 0)
    if spread not in RAY_ANGLE_SPREADS:  # a typo must not silently train the other variant
        raise UserError(f"ray-angle spread must be one of {', '.join(RAY_ANGLE_SPREADS)}, got {spread!r}")
    divisor = masked_mean_per_clip(vector_angle(target, axis), in_front).clamp_min(_MIN_RAY_SPREAD)
    if spread == "geometric":
        predicted = masked_mean_per_clip(vector_angle(pred, axis), in_front).clamp_min(_MIN_RAY_SPREAD)
        divisor = torch.sqrt(divisor * predicted)
    return vector_angle(pred, target) / divisor[:, None], defined


def masked_mean_per_clip(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of ``values`` (B, N) over ``mask`` (B, N) bool within each clip: (B,); 0 for an empty clip."""
    picked = torch.where(mask, values, torch.zeros_like(values))
    return picked.sum(1) / mask.sum(1).clamp_min(1).to(values.dtype)


def d4rt_loss(pred: dict[str, torch.Tensor], batch: dict[str, torch.Tensor],
              config: LossConfig | None = None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The total training loss and every term, from a batched forward and its targets.

    Args:
        pred: the model's training outputs, ``points (B,N,3)``, ``uv (B,N,2)``, ``visibility_logit (B,N)``,
            ``motion (B,N,3)``, ``normals (B,N,3)`` (unit), ``confidence (B,N)`` (positive); any dtype
            (computed in float32).
        batch: targets as the dataset yields them, ``points``, ``uv``, ``visibility`` (0/1), ``motion``,
            ``normals`` (zeros where undefined) and the masks ``valid (B,N)``, ``uv_valid (B,N)`` (bool),
            optionally ``normals_valid (B,N)`` (bool; default ``valid``).
        config: weights and choices; default :class:`LossConfig()` (the paper's).

    Returns:
        ``(total, terms)``: the scalar to minimise and a dict of detached scalars, each unweighted:
        ``3d`` (plain L3D), ``3d_confident`` (c * L3D), ``confidence`` (-log c), ``2d``, ``visibility``,
        ``motion``, ``normal``, plus ``confidence_mean`` (mean c) and ``valid_fraction``, ``uv_fraction``;
        with their weights > 0 also ``pose_rotation``, ``pose_translation``, ``camera_pair``,
        ``camera_pair_direction``, ``camera_pair_rotation``, ``log_depth``,
        ``aligned_depth``, ``body_relative_depth``, ``ray_angle``, ``dense_depth`` and ``correspondence``.
    """
    config = config or LossConfig()
    if config.weight_correspondence > 0 and "attention_log_probs" not in pred:
        raise UserError("loss weight_correspondence needs the model's attention_log_probs: call the model with "
                        "attention_block=config.attention_block")
    p = {k: pred[k].float() for k in PREDICTION_KEYS}
    valid = batch["valid"].bool()
    uv_valid = batch["uv_valid"].bool() & valid
    # Targets are zeroed where they are missing, so that nothing undefined (NaN) reaches any gradient.
    # Sources without normals (per-point tracks) mark them missing in an extra mask.
    normals_valid = batch["normals_valid"].bool() & valid if "normals_valid" in batch else valid
    t = {k: _zero_where_missing(batch[k].float(), valid) for k in ("points", "visibility", "motion")}
    t["uv"] = _zero_where_missing(batch["uv"].float(), uv_valid)
    t["normals"] = _zero_where_missing(batch["normals"].float(), normals_valid)
    target_points = t["points"]

    l3d = point_loss(p["points"], target_points, valid)
    confidence = p["confidence"]
    log_conf = torch.log(confidence)
    if config.confidence_weighting:
        error = l3d.detach() if config.confidence_stop_gradient else l3d
        weighted_3d = masked_mean(confidence * error, valid)
        point_term = config.weight_3d * weighted_3d - config.weight_confidence * masked_mean(log_conf, valid)
        if config.confidence_stop_gradient:  # the points' own term
            point_term = point_term + config.weight_3d * masked_mean(l3d, valid)
    else:
        weighted_3d = masked_mean(l3d, valid)
        point_term = config.weight_3d * weighted_3d

    l2d = masked_mean((p["uv"] - t["uv"]).abs().sum(-1), uv_valid)
    lvis = masked_mean(F.binary_cross_entropy_with_logits(p["visibility_logit"], t["visibility"],
                                                          reduction="none"), valid)
    pred_motion, target_motion = p["motion"], t["motion"]
    if config.normalise_motion:
        pred_motion = pred_motion / mean_depth(p["points"], valid).detach()[:, None, None]
        target_motion = target_motion / mean_depth(target_points, valid)[:, None, None]
    lmotion = masked_mean((pred_motion - target_motion).abs().sum(-1), valid)
    lnormal = masked_mean(1.0 - F.cosine_similarity(p["normals"], t["normals"], dim=-1, eps=1e-6), normals_valid)

    total = (point_term + config.weight_2d * l2d + config.weight_visibility * lvis
             + config.weight_motion * lmotion + config.weight_normal * lnormal)
    optional_terms = {}
    if config.weight_pose > 0:
        lrot, ltrans = pose_loss(pred, batch, mean_depth(p["points"], valid).detach(),
                                 mean_depth(target_points, valid), config.pose_translation)
        weight_translation = config.weight_pose if config.weight_pose_translation is None \
            else config.weight_pose_translation
        total = total + config.weight_pose * lrot + weight_translation * ltrans
        optional_terms = {"pose_rotation": lrot, "pose_translation": ltrans}
    if config.weight_camera_pair > 0:
        optional_terms["camera_pair"] = camera_pair_loss(p["points"], target_points, valid, batch,
                                                         mean_depth(p["points"], valid).detach(),
                                                         mean_depth(target_points, valid))
        total = total + config.weight_camera_pair * optional_terms["camera_pair"]
    if config.weight_camera_pair_direction > 0:
        optional_terms["camera_pair_direction"] = camera_pair_direction_loss(
            p["points"], target_points, valid, batch, mean_depth(p["points"], valid).detach(),
            mean_depth(target_points, valid))
        total = total + config.weight_camera_pair_direction * optional_terms["camera_pair_direction"]
    if config.weight_camera_pair_rotation > 0:
        optional_terms["camera_pair_rotation"] = camera_pair_rotation_loss(
            p["points"], target_points, valid, batch, mean_depth(p["points"], valid).detach(),
            mean_depth(target_points, valid))
        total = total + config.weight_camera_pair_rotation * optional_terms["camera_pair_rotation"]
    if config.weight_log_depth > 0:
        log_depth, in_front = log_depth_loss(p["points"], target_points, valid)
        optional_terms["log_depth"] = masked_mean(log_depth, in_front)
        total = total + config.weight_log_depth * optional_terms["log_depth"]
    if config.weight_aligned_depth > 0:
        aligned_depth, used = aligned_depth_loss(p["points"], target_points, batch["queries"], valid,
                                                    config.aligned_depth_alignment, config.aligned_depth_queries,
                                                    batch["uv"])
        optional_terms["aligned_depth"] = masked_mean(aligned_depth, used)
        total = total + config.weight_aligned_depth * optional_terms["aligned_depth"]
    if config.weight_body_relative_depth > 0:
        if "object_id" not in batch:
            raise UserError("loss weight_body_relative_depth needs batches with object_id (rendered clips; per-point "
                            "track datasets do not know which body a point lies on)")
        optional_terms["body_relative_depth"] = body_relative_depth_loss(
            p["points"], target_points, batch["queries"], valid, batch["uv"].float(), batch["object_id"])
        total = total + config.weight_body_relative_depth * optional_terms["body_relative_depth"]
    if config.weight_ray_angle > 0:
        ray_angle, defined = ray_angle_loss(p["points"], target_points, valid, config.ray_angle_spread)
        optional_terms["ray_angle"] = masked_mean(ray_angle, defined)
        total = total + config.weight_ray_angle * optional_terms["ray_angle"]
    if config.weight_dense_depth > 0:
        if "dense_log_depth" not in pred or "depth" not in batch:
            raise UserError("loss weight_dense_depth needs a model with dense_depth_head and batches with depth maps")
        optional_terms["dense_depth"] = dense_depth_loss(pred["dense_log_depth"], batch["depth"].float())
        total = total + config.weight_dense_depth * optional_terms["dense_depth"]
    if config.weight_correspondence > 0:
        optional_terms["correspondence"] = correspondence_loss(pred["attention_log_probs"], pred["token_grid"],
                                                               batch)
        total = total + config.weight_correspondence * optional_terms["correspondence"]
    terms = {
        "3d": masked_mean(l3d, valid),
        "3d_confident": weighted_3d if config.confidence_weighting else masked_mean(confidence * l3d, valid),
        "confidence": -masked_mean(log_conf, valid),
        "2d": l2d,
        "visibility": lvis,
        "motion": lmotion,
        "normal": lnormal,
        "confidence_mean": masked_mean(confidence, valid),
        "valid_fraction": valid.float().mean(),
        "uv_fraction": uv_valid.float().mean(),
        "total": total,
    } | optional_terms
    return total, {k: v.detach() for k, v in terms.items()}


def pose_loss(pred: dict[str, torch.Tensor], batch: dict[str, torch.Tensor], pred_scale: torch.Tensor,
              target_scale: torch.Tensor, translation_error: str = "l1") -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation and translation terms of the pose loss (module docstring), each a mean over the queries
    with t_cam != t_src. pred: ``relative_rotation (B,N,3,3)``, ``relative_translation (B,N,3)``; batch:
    ``queries (B,N,5)``, ``cam_to_world (B,T,4,4)``; scales: (B,) per-clip mean depths;
    ``translation_error``: ``l1`` (sum of absolute differences) or ``squared`` (squared distance)."""
    if "relative_rotation" not in pred:
        raise UserError("loss weight_pose > 0 needs a model with relative_pose_head: true")
    if "cam_to_world" not in batch:
        raise UserError("loss weight_pose > 0 needs cam_to_world in every training sample")
    queries = batch["queries"]
    moved = queries[..., 2].round() != queries[..., 4].round()
    relative = source_to_camera(batch)
    rotation_error = (pred["relative_rotation"].float() - relative[..., :3, :3]).abs().sum((-1, -2))
    difference = (pred["relative_translation"].float() / pred_scale[:, None, None]
                  - relative[..., :3, 3] / target_scale[:, None, None])
    if translation_error not in POSE_TRANSLATION_ERRORS:
        raise UserError(f"loss pose_translation must be one of {', '.join(POSE_TRANSLATION_ERRORS)}, "
                        f"got {translation_error!r}")
    translation = (difference.square() if translation_error == "squared" else difference.abs()).sum(-1)
    return masked_mean(rotation_error, moved), masked_mean(translation, moved)


def source_to_camera(batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Each query's rigid motion from camera t_src to camera t_cam, (B, N, 4, 4) float32, from the batch's
    ``queries (B, N, 5)`` and ``cam_to_world (B, T, 4, 4)`` (composed in float64)."""
    queries, c2w = batch["queries"], batch["cam_to_world"].double()
    t_src, t_cam = queries[..., 2].round().long(), queries[..., 4].round().long()
    clip = torch.arange(c2w.shape[0], device=c2w.device)[:, None]
    return (invert_rigid(c2w)[clip, t_cam] @ c2w[clip, t_src]).float()


def camera_pair_travels(pred_points: torch.Tensor, target_points: torch.Tensor, valid: torch.Tensor,
                        batch: dict[str, torch.Tensor], pred_scale: torch.Tensor,
                        target_scale: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The travel each camera-pair query and its twin imply, ``(P_pair - R P_twin) / s`` with the true rotation R
    from camera t_src to camera t_cam, for the prediction and the target (each divided by its own scale s).

    pred_points, target_points: (B, N, 3) in each query's camera t_cam; valid: (B, N) bool; batch: ``twin
    (B, N)`` long (the index of a camera-pair query's twin, -1 elsewhere), ``queries (B, N, 5)``,
    ``cam_to_world (B, T, 4, 4)``; scales: (B,) per-clip mean depths. Returns the predicted and true travels
    (B, N, 3) and ``paired`` (B, N) bool: the camera-pair queries whose point and twin's point exist.
    """
    if "twin" not in batch:
        raise UserError("the camera-pair loss terms need batches with twin queries: set "
                        "data.dataset.sampler.camera_pair_twins: true")
    if "cam_to_world" not in batch:
        raise UserError("the camera-pair loss terms need cam_to_world in every training sample")
    twin = batch["twin"].long()
    index = twin.clamp_min(0)
    paired = (twin >= 0) & valid & torch.gather(valid, 1, index)
    rotation = source_to_camera(batch)[..., :3, :3]

    def travel(points: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
        twins = torch.gather(points, 1, index[..., None].expand(-1, -1, 3))
        rotated = (rotation @ twins[..., None])[..., 0]
        return (points - rotated) / scale[:, None, None]

    return travel(pred_points, pred_scale), travel(target_points, target_scale), paired


def camera_pair_loss(pred_points: torch.Tensor, target_points: torch.Tensor, valid: torch.Tensor,
                     batch: dict[str, torch.Tensor], pred_scale: torch.Tensor,
                     target_scale: torch.Tensor) -> torch.Tensor:
    """The camera-pair term (module docstring): mean over the camera-pair queries whose point and twin's point
    exist of ``|(P_pair - R P_twin) / s_pred - (T_pair - R T_twin) / s_target|``. Arguments as
    :func:`camera_pair_travels`; returns a scalar (0 without pairs)."""
    predicted, true, paired = camera_pair_travels(pred_points, target_points, valid, batch, pred_scale,
                                                  target_scale)
    length = ((predicted - true).square().sum(-1) + 1e-12).sqrt()  # finite gradient where the travel is exact
    return masked_mean(length, paired)


def camera_pair_direction_loss(pred_points: torch.Tensor, target_points: torch.Tensor, valid: torch.Tensor,
                               batch: dict[str, torch.Tensor], pred_scale: torch.Tensor,
                               target_scale: torch.Tensor) -> torch.Tensor:
    """The camera-pair direction term (module docstring): mean over the pairs of :func:`camera_pair_travels`
    whose true travel is at least ``_MIN_PAIR_TRAVEL`` of ``|t / |t| - p / max(|p|, _MIN_PAIR_TRAVEL_LENGTH)|``
    (p, t the predicted and true travels), in [0, 2]: 0 when the directions agree, 1 for a vanished prediction.
    Arguments as :func:`camera_pair_travels`; returns a scalar (0 without such pairs)."""
    predicted, true, paired = camera_pair_travels(pred_points, target_points, valid, batch, pred_scale,
                                                  target_scale)
    true_length = true.norm(dim=-1, keepdim=True)
    moved = paired & (true_length[..., 0] >= _MIN_PAIR_TRAVEL)
    true_direction = true / true_length.clamp_min(_MIN_PAIR_TRAVEL)
    predicted_direction = predicted / predicted.norm(dim=-1, keepdim=True).clamp_min(_MIN_PAIR_TRAVEL_LENGTH)
    distance = ((predicted_direction - true_direction).square().sum(-1) + 1e-12).sqrt()
    return masked_mean(distance, moved)


def camera_pair_rotations(pred_points: torch.Tensor, target_points: torch.Tensor, valid: torch.Tensor,
                          batch: dict[str, torch.Tensor], pred_scale: torch.Tensor,
                          target_scale: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per clip and camera pair (t_src, t_cam), the linearised rotation error of the rigid fit between the pairs'
    answers and their twins' (module docstring), for the prediction and the target. Arguments as
    :func:`camera_pair_travels`. Returns ``(omega_pred (G, 3), omega_target (G, 3), usable (G,) bool)`` over
    G = B * T * T groups (T the batch's frames), radians; groups that are not ``usable`` hold zeros."""
    queries = batch["queries"]
    frames = batch["cam_to_world"].shape[1]
    groups = queries.shape[0] * frames * frames
    clip = torch.arange(queries.shape[0], device=queries.device)[:, None]
    group = ((clip * frames + queries[..., 2].round().long()) * frames + queries[..., 4].round().long())
    rotation = source_to_camera(batch)[..., :3, :3]
    twin = batch["twin"].long().clamp_min(0)

    def omega(points: torch.Tensor, scale: torch.Tensor, paired: torch.Tensor):
        twins = torch.gather(points, 1, twin[..., None].expand(-1, -1, 3))
        arm = (rotation @ twins[..., None])[..., 0] / scale[:, None, None]  # the twin seen from camera t_cam
        travel = points / scale[:, None, None] - arm
        ids = group[paired]
        count = torch.zeros(groups, device=points.device, dtype=points.dtype).index_add_(
            0, ids, torch.ones_like(ids, dtype=points.dtype))

        def group_mean(x: torch.Tensor) -> torch.Tensor:
            sums = torch.zeros(groups, 3, device=x.device, dtype=x.dtype).index_add_(0, ids, x[paired])
            return sums / count.clamp_min(1)[:, None]

        d = (arm - group_mean(arm)[group])[paired]
        r = (travel - group_mean(travel)[group])[paired]
        lever = (d.square().sum(-1)[:, None, None] * torch.eye(3, device=d.device, dtype=d.dtype)
                 - d[:, :, None] * d[:, None, :])
        matrix = torch.zeros(groups, 3, 3, device=d.device, dtype=d.dtype).index_add_(0, ids, lever)
        moment = torch.zeros(groups, 3, device=d.device, dtype=d.dtype).index_add_(
            0, ids, torch.linalg.cross(d, r))
        return matrix, moment, count

    pair_mask = (batch["twin"] >= 0) & valid & torch.gather(valid, 1, twin)
    pred_matrix, pred_moment, count = omega(pred_points, pred_scale, pair_mask)
    target_matrix, target_moment, _ = omega(target_points, target_scale, pair_mask)
    with torch.no_grad():  # which groups determine a rotation: enough pairs spread off a line, on both sides
        smallest = torch.minimum(torch.linalg.eigvalsh(pred_matrix)[:, 0], torch.linalg.eigvalsh(target_matrix)[:, 0])
        usable = (count >= 3) & (smallest >= _MIN_PAIR_SPREAD * count)
    eye = torch.eye(3, device=pred_matrix.device, dtype=pred_matrix.dtype)

    def solve(matrix: torch.Tensor, moment: torch.Tensor) -> torch.Tensor:
        safe = torch.where(usable[:, None, None], matrix, eye)  # unusable groups: a harmless system, zeroed below
        return torch.where(usable[:, None], torch.linalg.solve(safe, moment), 0.0)

    return solve(pred_matrix, pred_moment), solve(target_matrix, target_moment), usable


def camera_pair_rotation_loss(pred_points: torch.Tensor, target_points: torch.Tensor, valid: torch.Tensor,
                              batch: dict[str, torch.Tensor], pred_scale: torch.Tensor,
                              target_scale: torch.Tensor) -> torch.Tensor:
    """The camera-pair rotation term (module docstring): mean over the usable groups of :func:`camera_pair_rotations`
    of ``|omega_pred - omega_target|`` (radians). Arguments as :func:`camera_pair_travels`; returns a scalar (0, still
    attached to the graph, without usable groups)."""
    if "twin" not in batch:
        raise UserError("the camera-pair loss terms need batches with twin queries: set "
                        "data.dataset.sampler.camera_pair_twins: true")
    if "cam_to_world" not in batch:
        raise UserError("the camera-pair loss terms need cam_to_world in every training sample")
    predicted, true, usable = camera_pair_rotations(pred_points, target_points, valid, batch, pred_scale,
                                                    target_scale)
    length = ((predicted - true).square().sum(-1) + 1e-12).sqrt()
    return masked_mean(length, usable)

def _zero_where_missing(target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``target`` (B, N, ...) with the entries of queries outside ``mask`` (B, N) set to 0."""
    shape = mask.shape + (1,) * (target.ndim - mask.ndim)
    return torch.where(mask.reshape(shape), target, torch.zeros_like(target))
