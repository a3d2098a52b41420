"""Render frames of a synthetic scene: RGB plus exact geometry buffers.

Geometry buffers (z-depth, camera-frame normals, object ids) are point-sampled at pixel centres, so
they are exact ground truth for those pixels and never blend two surfaces. RGB is anti-aliased:
textures are band-limited to the pixel footprint (textures.py) and pixels on geometric or material
edges are supersampled on an n x n grid. Shading: a directional sun (outdoors) or a point light
(rooms), Lambert diffuse plus Blinn-Phong specular, an ambient term, and optional cast shadows.
"""

from __future__ import annotations

import numpy as np
import torch

from d4rt.geometry.camera import pixel_rays
from d4rt.synthetic import textures
from d4rt.geometry.transforms import apply_rotation
from d4rt.synthetic.raytrace import Hits, SceneTracer, _dot, present_ids
from d4rt.synthetic.scene import SceneDescription

# Rays per chunk of frames: bounds memory at about 1 GB on any resolution.
CHUNK_RAYS = 1 << 19


def render(scene: SceneDescription, intrinsics: np.ndarray, cam_to_world: np.ndarray, object_to_world: np.ndarray,
           height: int, width: int, device="cpu", aa_samples: int = 2, geometry_only: bool = False) -> dict:
    """Render every frame. intrinsics: (T, 3, 3); cam_to_world: (T, 4, 4); object_to_world: (T, K, 4, 4).

    Returns numpy arrays: ``rgb (T,H,W,3) uint8`` (absent if geometry_only), ``depth (T,H,W) float32``
    (z in the camera frame), ``normals (T,H,W,3) float32`` (unit, camera frame, facing the camera),
    ``object_ids (T,H,W) uint8``.
    """
    tracer = SceneTracer(scene, object_to_world, device=device, dtype=torch.float32)
    num_frames = tracer.num_frames
    k_all = torch.as_tensor(np.asarray(intrinsics), dtype=torch.float64, device=tracer.device)
    c2w_all = torch.as_tensor(np.asarray(cam_to_world), dtype=torch.float64, device=tracer.device)
    out = {"depth": [], "normals": [], "object_ids": []}
    if not geometry_only:
        out["rgb"] = []
    per_chunk = max(1, CHUNK_RAYS // (height * width))
    for start in range(0, num_frames, per_chunk):
        frames = torch.arange(start, min(start + per_chunk, num_frames), device=tracer.device)
        chunk = _render_chunk(tracer, frames, k_all[frames], c2w_all[frames], height, width, aa_samples, geometry_only)
        for key, value in chunk.items():
            out[key].append(value.cpu().numpy())
    return {key: np.concatenate(value) for key, value in out.items()}


def _render_chunk(tracer, frames, intrinsics, cam_to_world, height, width, aa_samples, geometry_only):
    """Render frames ``frames``; intrinsics (F, 3, 3) and cam_to_world (F, 4, 4) are float64."""
    dev, dt = tracer.device, tracer.dtype
    ys, xs = torch.meshgrid(torch.arange(height, device=dev, dtype=torch.float64),
                            torch.arange(width, device=dev, dtype=torch.float64), indexing="ij")
    xy = torch.stack([xs, ys], -1)
    rot = cam_to_world[:, :3, :3]
    # Rays in float64 (exact pixel-centre directions); traced in the tracer's dtype (fast), refined
    # in float64 by ``surface``. Camera z of every direction is 1, so the ray parameter is z-depth.
    dirs64 = apply_rotation(rot[:, None, None], pixel_rays(xy[None], intrinsics[:, None, None]))  # (F, H, W, 3)
    origins64 = cam_to_world[:, :3, 3]
    rects = tracer.projected_rects(frames, cam_to_world.to(dt), intrinsics.to(dt), height, width)
    hits = tracer.trace_grid(frames, origins64.to(dt), dirs64.to(dt), rects)

    f = frames.shape[0]
    hw = height * width
    flat_frames = frames[:, None].expand(f, hw).reshape(-1)
    flat_origins = origins64[:, None].expand(f, hw, 3).reshape(-1, 3)
    flat_dirs = dirs64.reshape(-1, 3)
    flat_hits = Hits(hits.t.reshape(-1), hits.obj.reshape(-1), hits.face.reshape(-1))
    surf = tracer.surface(flat_frames, flat_origins, flat_dirs, flat_hits, exact_depth=True)
    # Which body a pixel sees is decided in float32; next to a silhouette that decision may differ from
    # exact arithmetic, so those pixels (and any whose body the float64 ray misses) are cast again in
    # float64, exactly as the ground-truth oracle casts them.
    recast = torch.nonzero(_neighbour_changes(hits.obj, hits.face).reshape(-1) | surf["lost"]).squeeze(1)
    if recast.numel():
        fr, o, d = flat_frames[recast], flat_origins[recast], flat_dirs[recast]
        exact_hits = tracer.trace_rays(fr, o, d, dtype=torch.float64)
        exact = tracer.surface(fr, o, d, exact_hits, exact_depth=True, dtype=torch.float64)
        flat_hits.t[recast] = exact_hits.t.to(dt)
        flat_hits.obj[recast] = exact_hits.obj
        flat_hits.face[recast] = exact_hits.face
        surf["t_exact"][recast] = exact["t_exact"]
        for key in ("world_point", "world_normal", "local_point"):
            surf[key][recast] = exact[key].to(dt)
    normal_cam = apply_rotation(rot.transpose(-1, -2)[:, None], surf["world_normal"].reshape(f, hw, 3))
    result = {
        "depth": surf["t_exact"].reshape(f, height, width).to(torch.float32),
        "normals": normal_cam.reshape(f, height, width, 3).to(torch.float32),
        "object_ids": flat_hits.obj.reshape(f, height, width),
    }
    if geometry_only:
        return result

    focal = intrinsics[:, 0, 0].to(dt)[:, None].expand(f, hw).reshape(-1)
    color = shade(tracer, flat_frames, flat_origins.to(dt), flat_dirs.to(dt), flat_hits, surf, focal)
    color = color.reshape(f, height, width, 3)
    if aa_samples > 1:
        edges = _neighbour_changes(result["object_ids"], flat_hits.face.reshape(f, height, width), result["normals"])
        if edges.any():
            color[edges] = _supersample(tracer, frames, intrinsics.to(dt), cam_to_world.to(dt), edges, aa_samples)
    result["rgb"] = _to_srgb8(color)
    return result


def shade(tracer: SceneTracer, frames, origins, dirs, hits: Hits, surf: dict, focal: torch.Tensor) -> torch.Tensor:
    """Linear RGB radiance of hit rays (M, 3). focal: (M,) focal length (px) of each ray's camera.

    Vectors are handled as three contiguous component planes: dot products over (M, 3) rows are several
    times slower on the CPU.
    """
    scene = tracer.scene
    light = scene.light
    dev, dt = tracer.device, tracer.dtype
    point, normal = surf["world_point"], surf["world_normal"]
    n = normal.T.contiguous()
    d = dirs.T.contiguous()
    ray_len = torch.sqrt(_dot(d, d))
    view = -d / ray_len
    cos_view = _dot(n, view).abs().clamp(min=0.2)
    footprint = hits.t * ray_len / focal / cos_view  # width of one pixel on the surface (m)

    if light.kind == "directional":
        to_light = torch.tensor(light.direction, dtype=dt, device=dev)[:, None].expand_as(n)
        dist = torch.full_like(hits.t, float("inf"))
        attenuation = torch.ones_like(hits.t)
    else:
        delta = torch.tensor(light.position, dtype=dt, device=dev)[:, None] - point.T
        dist = torch.sqrt(_dot(delta, delta))
        to_light = delta / dist
        attenuation = 1.0 / (1.0 + (dist / light.falloff) ** 2)
    n_dot_l = _dot(n, to_light).clamp(min=0.0)
    lit = attenuation * (n_dot_l > 0)
    if scene.shadows:
        lit = lit * ~_in_shadow(tracer, frames, point, normal, to_light.T, dist, hits, n_dot_l)
    half = to_light + view
    half = half / torch.sqrt(_dot(half, half)).clamp(min=1e-8)
    n_dot_h = _dot(n, half).clamp(min=0.0)
    light_color = torch.tensor(light.color, dtype=dt, device=dev)
    ambient = torch.tensor(light.ambient, dtype=dt, device=dev)

    out = torch.empty_like(point)
    obj = hits.obj.long()
    face = hits.face.long()
    for k in present_ids(obj):
        body = scene.bodies[k]
        in_body = torch.nonzero(obj == k).squeeze(1)
        material_index = face[in_body] % len(body.materials)
        for m_i, material in enumerate(body.materials):
            idx = in_body if len(body.materials) == 1 else in_body[material_index == m_i]
            if idx.numel() == 0:
                continue
            alb = textures.albedo(material, surf["local_point"][idx], footprint[idx])
            if material.emissive:
                out[idx] = alb
                continue
            diffuse = ambient + light_color * (n_dot_l[idx] * lit[idx])[:, None]
            if material.specular > 0:
                spec = material.specular * n_dot_h[idx] ** material.shininess * lit[idx]
                out[idx] = alb * diffuse + light_color * spec[:, None]
            else:
                out[idx] = alb * diffuse
    return out


def _in_shadow(tracer, frames, point, normal, to_light, dist, hits, n_dot_l) -> torch.Tensor:
    """Whether a foreground body blocks the light (the environment casts no shadows). point, normal,
    to_light: (M, 3); dist, n_dot_l: (M,)."""
    shadowed = torch.zeros_like(hits.t, dtype=torch.bool)
    emissive = torch.zeros_like(shadowed)
    for k, body in enumerate(tracer.scene.bodies):
        if any(m.emissive for m in body.materials):
            emissive |= hits.obj == k  # conservative: emissive bodies are not lit anyway
    idx = torch.nonzero((n_dot_l > 0) & ~emissive).squeeze(1)
    if idx.numel() == 0:
        return shadowed
    eps = 1e-3 * (1.0 + hits.t[idx])
    origin = point[idx] + normal[idx] * eps[:, None]
    t_max = dist[idx]
    blocked = tracer.trace_rays(frames[idx], origin, to_light[idx], t_min=1e-5, include_environment=False,
                                t_max=t_max)
    shadowed[idx] = blocked.t < t_max
    return shadowed


def _neighbour_changes(obj: torch.Tensor, face: torch.Tensor, normals: torch.Tensor | None = None) -> torch.Tensor:
    """Pixels whose 4-neighbourhood shows another body or face (or, given normals, a crease):
    (F, H, W) bool.

    All primitives are convex, so a depth discontinuity always comes with a change of body or face
    (the room's walls are separate faces): no depth test is needed, and none would misfire on
    grazing planes, whose depth legitimately changes fast from pixel to pixel.
    """
    edge = torch.zeros_like(obj, dtype=torch.bool)
    for dim in (1, 2):
        n = obj.shape[dim]
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[dim], b[dim] = slice(0, n - 1), slice(1, n)
        a, b = tuple(a), tuple(b)
        diff = (obj[a] != obj[b]) | (face[a] != face[b])
        if normals is not None:
            diff |= (normals[a] * normals[b]).sum(-1) < 0.95
        edge[a] |= diff
        edge[b] |= diff
    return edge


def _supersample(tracer, frames, intrinsics, cam_to_world, edges, n: int) -> torch.Tensor:
    """Mean radiance of an n x n stratified grid of rays inside each edge pixel: (E, 3).

    All E * n * n rays are cast in one batch; the mean is accumulated in a fixed order so the result
    is bit-reproducible.
    """
    dev, dt = tracer.device, tracer.dtype
    fi, yi, xi = torch.nonzero(edges, as_tuple=True)
    offsets = (torch.arange(n, device=dev, dtype=dt) + 0.5) / n - 0.5
    oy, ox = (o.reshape(-1) for o in torch.meshgrid(offsets, offsets, indexing="ij"))
    s = oy.shape[0]
    fi_s = fi.repeat_interleave(s)
    xy = torch.stack([(xi.to(dt)[:, None] + ox).reshape(-1), (yi.to(dt)[:, None] + oy).reshape(-1)], -1)
    pose, k = cam_to_world.index_select(0, fi_s), intrinsics.index_select(0, fi_s)
    d = apply_rotation(pose[:, :3, :3], pixel_rays(xy, k))
    o = pose[:, :3, 3]
    fr = frames[fi_s]
    hits = tracer.trace_rays(fr, o, d)
    surf = tracer.surface(fr, o, d, hits)
    color = shade(tracer, fr, o, d, hits, surf, k[:, 0, 0]).reshape(-1, s, 3)
    total = color[:, 0]
    for i in range(1, s):
        total = total + color[:, i]
    return total / s


def _to_srgb8(linear: torch.Tensor) -> torch.Tensor:
    """Linear radiance -> 8-bit sRGB-like gamma 2.2, clipped at white."""
    return torch.round(linear.clamp(0.0, 1.0) ** (1.0 / 2.2) * 255.0).to(torch.uint8)

