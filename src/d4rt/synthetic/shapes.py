"""Ray intersection and surface normals of the canonical primitives, in the primitive's own frame.

Every body is a canonical primitive (below) scaled per axis by its half-extents and placed by a rigid
pose. A ray x(t) = o + t d in the world maps to o_c + t d_c in the canonical frame with the SAME t
(the map is affine), so the ray parameter found here is the world one: for camera rays whose
direction has camera z = 1 it is exactly the z-depth.

Canonical primitives (all inside [-1, 1]^3):
- sphere:   |p| <= 1                                  (an ellipsoid once scaled)
- box:      |p_i| <= 1                                 (faces 0..5 = axis * 2 + (side > 0))
- cylinder: p_x^2 + p_y^2 <= 1, |p_z| <= 1             (face 0 = side, 1 = caps)
- cone:     p_x^2 + p_y^2 <= r(p_z)^2, |p_z| <= 1, with r(-1) = 1 and r(1) = r_top (a frustum)
- room:     the box seen from inside (the camera is inside; the ray's exit point is the hit)
- outdoor:  ground plane p_z = 0 inside a sky dome |p| = 1 seen from inside (face 0 ground, 1 sky)

Functions take the ray as separate x, y, z component tensors (broadcastable) and return
(t, face) with t = inf where the ray misses or hits only at t <= t_min.
"""

from __future__ import annotations

import torch

Components = tuple[torch.Tensor, torch.Tensor, torch.Tensor]

SHAPES = ("sphere", "box", "cylinder", "cone")
ENVIRONMENTS = ("room", "outdoor")
# Number of distinct faces (material slots) each primitive reports.
NUM_FACES = {"sphere": 1, "box": 6, "cylinder": 2, "cone": 2, "room": 6, "outdoor": 2}


def _inf_like(x: torch.Tensor) -> torch.Tensor:
    return torch.full_like(x, float("inf"))


def _first_positive_root(a, b_half, c, t_min, use_far: bool = False):
    """Roots of a t^2 + 2 b_half t + c = 0: the near root if > t_min (or the far root if use_far)."""
    disc = b_half * b_half - a * c
    sq = torch.sqrt(torch.clamp(disc, min=0.0))
    if use_far:
        t = (-b_half + sq) / a
    else:
        t = (-b_half - sq) / a
    ok = (disc >= 0) & (t > t_min)
    return torch.where(ok, t, _inf_like(t))


def _unit_sphere(o: Components, d: Components, t_min: float, far: bool = False) -> torch.Tensor:
    """Ray parameter of the hit with |p| = 1: the near root (from outside) or the far one (inside)."""
    ox, oy, oz = o
    dx, dy, dz = d
    a = dx * dx + dy * dy + dz * dz
    b = ox * dx + oy * dy + oz * dz
    c = ox * ox + oy * oy + oz * oz - 1.0
    return _first_positive_root(a, b, c, t_min, use_far=far)


def intersect_sphere(o: Components, d: Components, t_min: float):
    t = _unit_sphere(o, d, t_min)
    return t, torch.zeros_like(t, dtype=torch.uint8)


def _slabs(o: Components, d: Components):
    """Per-axis entry/exit parameters of the slabs |p_i| <= 1."""
    near, far = [], []
    for oi, di in zip(o, d):
        inv = 1.0 / di  # +-inf for axis-parallel rays: the slab test still works
        t1 = (-1.0 - oi) * inv
        t2 = (1.0 - oi) * inv
        near.append(torch.fmin(t1, t2))
        far.append(torch.fmax(t1, t2))
    return near, far


def intersect_box(o: Components, d: Components, t_min: float):
    near, far = _slabs(o, d)
    t_enter = torch.maximum(torch.maximum(near[0], near[1]), near[2])
    t_exit = torch.minimum(torch.minimum(far[0], far[1]), far[2])
    ok = (t_exit >= t_enter) & (t_enter > t_min)
    t = torch.where(ok, t_enter, _inf_like(t_enter))
    # The entry face is on the axis whose slab is entered last, on the side the ray comes from.
    axis = torch.where(near[0] >= near[1], 0, 1)
    axis = torch.where(torch.maximum(near[0], near[1]) >= near[2], axis, 2)
    d_axis = torch.where(axis == 0, d[0], torch.where(axis == 1, d[1], d[2]))
    face = axis * 2 + (d_axis < 0).long()
    return t, face.to(torch.uint8)


def intersect_room(o: Components, d: Components, t_min: float):
    _, far = _slabs(o, d)
    t = torch.minimum(torch.minimum(far[0], far[1]), far[2])
    axis = torch.where(far[0] <= far[1], 0, 1)
    axis = torch.where(torch.minimum(far[0], far[1]) <= far[2], axis, 2)
    d_axis = torch.where(axis == 0, d[0], torch.where(axis == 1, d[1], d[2]))
    face = axis * 2 + (d_axis > 0).long()
    t = torch.where(t > t_min, t, _inf_like(t))
    return t, face.to(torch.uint8)


def _caps(o: Components, d: Components, t_min: float, radius_bottom: float, radius_top: float):
    """Nearest hit of the discs z = -1 (radius_bottom) and z = +1 (radius_top)."""
    ox, oy, oz = o
    dx, dy, dz = d
    best = None
    for z, r in ((-1.0, radius_bottom), (1.0, radius_top)):
        t = (z - oz) / dz
        x = ox + t * dx
        y = oy + t * dy
        ok = (t > t_min) & (x * x + y * y <= r * r)
        t = torch.where(ok, t, _inf_like(t))
        best = t if best is None else torch.minimum(best, t)
    return best


def intersect_cylinder(o: Components, d: Components, t_min: float):
    ox, oy, oz = o
    dx, dy, dz = d
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    c = ox * ox + oy * oy - 1.0
    t_side = _first_positive_root(a, b, c, t_min)
    z = oz + t_side * dz
    t_side = torch.where(z.abs() <= 1.0, t_side, _inf_like(t_side))
    t_caps = _caps(o, d, t_min, 1.0, 1.0)
    return _pick(t_side, t_caps)


def cone_coefficients(r_top: float) -> tuple[float, float]:
    """r(z) = a + b z with r(-1) = 1 and r(1) = r_top."""
    return (1.0 + r_top) / 2.0, (r_top - 1.0) / 2.0


def intersect_cone(o: Components, d: Components, t_min: float, r_top: float):
    ox, oy, oz = o
    dx, dy, dz = d
    ca, cb = cone_coefficients(r_top)
    r0 = ca + cb * oz
    a = dx * dx + dy * dy - cb * cb * dz * dz
    b = ox * dx + oy * dy - cb * r0 * dz
    c = ox * ox + oy * oy - r0 * r0
    # The double cone x^2 + y^2 = r(z)^2 has two nappes; both roots may be needed, so test each.
    disc = b * b - a * c
    sq = torch.sqrt(torch.clamp(disc, min=0.0))
    t_side = None
    for sign in (-1.0, 1.0):
        t = (-b + sign * sq) / a
        z = oz + t * dz
        ok = (disc >= 0) & (t > t_min) & (z.abs() <= 1.0) & (ca + cb * z >= 0)
        t = torch.where(ok, t, _inf_like(t))
        t_side = t if t_side is None else torch.minimum(t_side, t)
    t_caps = _caps(o, d, t_min, 1.0, r_top)
    return _pick(t_side, t_caps)


def intersect_outdoor(o: Components, d: Components, t_min: float):
    t_dome = _unit_sphere(o, d, t_min, far=True)
    t_ground = -o[2] / d[2]
    t_ground = torch.where((t_ground > t_min) & (t_ground < t_dome), t_ground, _inf_like(t_ground))
    return _pick(t_ground, t_dome)


def _pick(t_first: torch.Tensor, t_second: torch.Tensor):
    """Nearest of two candidate hits; face 0 for the first, 1 for the second."""
    second = t_second < t_first
    return torch.where(second, t_second, t_first), second.to(torch.uint8)


def intersect(shape: str, o: Components, d: Components, t_min: float, r_top: float = 0.0):
    """Dispatch to the primitive's intersection. Returns (t, face)."""
    if shape == "sphere":
        return intersect_sphere(o, d, t_min)
    if shape == "box":
        return intersect_box(o, d, t_min)
    if shape == "cylinder":
        return intersect_cylinder(o, d, t_min)
    if shape == "cone":
        return intersect_cone(o, d, t_min, r_top)
    if shape == "room":
        return intersect_room(o, d, t_min)
    if shape == "outdoor":
        return intersect_outdoor(o, d, t_min)
    raise ValueError(f"unknown primitive {shape!r}")


def canonical_normal(shape: str, p: torch.Tensor, face: torch.Tensor, r_top: float = 0.0) -> torch.Tensor:
    """Unnormalised outward normal of the canonical primitive at surface points.

    p: (M, 3) canonical points on the surface; face: (M,) from ``intersect``. Returns (M, 3).
    Environments (room, dome) return the normal pointing into the scene (towards the camera).
    """
    zeros = torch.zeros_like(p)
    if shape == "sphere":
        return p
    if shape in ("box", "room"):
        axis_normal = zeros.scatter(1, (face // 2).long()[:, None], 1.0)
        plus_side = torch.where(face % 2 == 1, 1.0, -1.0).to(p.dtype)[:, None]
        # Box: the entry face on the + side faces +axis. Room: the exit wall on the + side faces -axis.
        return axis_normal * plus_side if shape == "box" else -axis_normal * plus_side
    if shape in ("cylinder", "cone"):
        cap = face == 1
        if shape == "cylinder":
            side_n = torch.stack([p[:, 0], p[:, 1], torch.zeros_like(p[:, 0])], 1)
        else:
            ca, cb = cone_coefficients(r_top)
            side_n = torch.stack([p[:, 0], p[:, 1], -cb * (ca + cb * p[:, 2])], 1)
        cap_n = torch.stack([torch.zeros_like(p[:, 0]), torch.zeros_like(p[:, 0]), torch.sign(p[:, 2])], 1)
        return torch.where(cap[:, None], cap_n, side_n)
    if shape == "outdoor":
        ground = torch.zeros_like(p)
        ground[:, 2] = 1.0
        return torch.where((face == 0)[:, None], ground, -p)
    raise ValueError(f"unknown primitive {shape!r}")
