"""Random scenes: environment, bodies, materials, light, camera path and body motion, from one seed.

Everything here is numpy float64 driven by ``numpy.random.default_rng(seed)``, so a seed and the
options determine the scene exactly. Motion is defined in continuous time (seconds); frame k is shown
at time k * time_stride / fps. World frame: z up, ground / floor at z = 0, metres.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import asdict, dataclass

import numpy as np

from d4rt.errors import UserError
from d4rt.geometry.transforms import rigid, rotation_about_axis
from d4rt.synthetic.scene import Body, Light, Material, SceneDescription

# The moving kinds a random scene draws from; "walk" only when SceneOptions.walk_fraction asks for it, so the
# scenes of every existing seed (and the frozen benchmarks built on them) stay the same.
MOVING_CAMERA_MOTIONS = ("orbit", "forward", "pan", "truck", "handheld")
CAMERA_MOTIONS = (*MOVING_CAMERA_MOTIONS, "static", "walk")
OBJECT_SHAPES = ("sphere", "box", "cylinder", "cone")
MAX_BODIES = 255  # object ids are stored as uint8
# Options added after synthetic-dynamic-v1 was frozen, with their defaults: a scene's description records them
# only when set otherwise, so every earlier scene's description (and the benchmark's fingerprint) is unchanged.
_LATER_OPTIONS = {"walk_fraction": 0.0}


@dataclass
class SceneOptions:
    """Options of the random scene; ``None`` means "drawn at random from the seed".

    environment: "room" or "outdoor". num_objects: foreground rigid objects (an articulated object
    counts its parts separately, on top). camera_motion: one of CAMERA_MOTIONS. shake: add hand-held
    shake. fov_degrees: range of the field of view across the image's longer side. zoom: focal length
    changes smoothly within the clip. articulated: add a jointed arm of rigid parts.
    moving_fraction: probability that an object moves. fps / time_stride: frame k is at time
    k * time_stride / fps seconds. principal_point_jitter: principal point offset from the image
    centre, as a fraction of the image size (0 = centred, like the paper's intrinsics recipe assumes).
    """

    environment: str | None = None
    num_objects: int | None = None
    camera_motion: str | None = None
    shake: bool | None = None
    fov_degrees: tuple[float, float] = (35.0, 90.0)
    zoom: bool | None = None
    articulated: bool | None = None
    moving_fraction: float = 0.7
    fps: float = 12.0
    time_stride: int = 1
    principal_point_jitter: float = 0.0
    shadows: bool = True
    walk_fraction: float = 0.0

    def validate(self) -> None:
        if self.environment not in (None, "room", "outdoor"):
            raise UserError(f"environment must be 'room' or 'outdoor', got {self.environment!r}")
        if self.camera_motion not in (None,) + CAMERA_MOTIONS:
            raise UserError(f"camera_motion must be one of {CAMERA_MOTIONS}, got {self.camera_motion!r}")
        if self.num_objects is not None and not 0 <= self.num_objects <= MAX_BODIES - 4:
            raise UserError(f"num_objects must be between 0 and {MAX_BODIES - 4}, got {self.num_objects}")
        lo, hi = self.fov_degrees
        if not 1.0 <= lo <= hi < 170.0:
            raise UserError(f"fov_degrees must satisfy 1 <= low <= high < 170, got {self.fov_degrees}")
        if not 0.0 <= self.moving_fraction <= 1.0:
            raise UserError(f"moving_fraction must be in [0, 1], got {self.moving_fraction}")
        if self.fps <= 0 or int(self.time_stride) != self.time_stride or self.time_stride < 1:
            raise UserError(f"fps must be > 0 and time_stride a positive integer, got {self.fps}, {self.time_stride}")
        if not 0.0 <= self.walk_fraction <= 1.0:
            raise UserError(f"walk_fraction must be in [0, 1], got {self.walk_fraction}")
        if not 0.0 <= self.principal_point_jitter < 0.5:
            raise UserError(f"principal_point_jitter must be in [0, 0.5), got {self.principal_point_jitter}")


@dataclass
class SampledScene:
    """A scene description plus its per-frame cameras and body poses."""

    description: SceneDescription
    intrinsics: np.ndarray  # (T, 3, 3) pixels
    cam_to_world: np.ndarray  # (T, 4, 4)
    object_to_world: np.ndarray  # (T, K, 4, 4)


# --------------------------------------------------------------------------------------------------
# Materials


def _color(rng, sat=(0.2, 0.9), val=(0.25, 0.95)) -> list[float]:
    """A random colour, drawn in HSV, returned in linear RGB."""
    r, g, b = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(*sat), rng.uniform(*val))
    return [float(c) ** 2.2 for c in (r, g, b)]


def _unit(rng) -> list[float]:
    v = rng.normal(size=3)
    return (v / np.linalg.norm(v)).tolist()


def random_material(rng, role: str, extent: float = 1.0, depth: int = 0) -> Material:
    """A random material for a body of size ``extent`` (m); role: object, floor, wall, ceiling, ground."""
    if role == "object":
        patterns, weights, freq = ("solid", "noise", "marble", "stripes", "checker", "dots", "gradient"), \
            (0.08, 0.2, 0.14, 0.16, 0.16, 0.12, 0.14), (1.5 / extent, 8.0 / extent)
    elif role in ("floor", "ground"):
        patterns, weights, freq = ("checker", "stripes", "noise", "marble", "dots"), (0.3, 0.2, 0.25, 0.15, 0.1), (0.5, 2.5)
    elif role == "wall":
        patterns, weights, freq = ("noise", "stripes", "gradient", "checker", "marble", "dots"), \
            (0.3, 0.2, 0.15, 0.1, 0.15, 0.1), (0.4, 2.0)
    else:  # ceiling
        patterns, weights, freq = ("noise", "solid", "checker"), (0.5, 0.3, 0.2), (0.3, 1.5)
    pattern = str(rng.choice(patterns, p=np.array(weights) / sum(weights)))
    colors = [_color(rng) for _ in range(3 if pattern == "gradient" and rng.uniform() < 0.5 else 2)]
    if rng.uniform() < 0.3:  # low-contrast materials exist too: colour alone must not give things away
        colors[1] = [min(1.0, c * rng.uniform(0.6, 1.4)) for c in colors[0]]
    material = Material(
        pattern=pattern,
        colors=colors,
        frequency=float(np.exp(rng.uniform(np.log(freq[0]), np.log(freq[1])))),
        direction=_unit(rng),
        offset=rng.uniform(-5, 5, size=3).tolist(),
        extent=float(extent),
        noise_seed=int(rng.integers(0, 2**31 - 1)),
        noise_frequency=float(np.exp(rng.uniform(np.log(0.8 / extent), np.log(4.0 / extent)))),
        grain=float(rng.uniform(0.03, 0.25)),
        specular=float(rng.choice([0.0, rng.uniform(0.05, 0.6)], p=[0.4, 0.6])) if role == "object" else
        float(rng.uniform(0.0, 0.15)),
        shininess=float(np.exp(rng.uniform(np.log(6), np.log(80)))),
    )
    if depth == 0 and rng.uniform() < 0.2:  # a mixture of two textures through a noise mask
        material.secondary = random_material(rng, role, extent, depth=1)
    return material


def _sky_material(rng, radius: float) -> Material:
    """Emissive sky: a horizon-to-zenith gradient with soft clouds (a low-frequency noise mixture)."""
    horizon, zenith = _color(rng, (0.05, 0.3), (0.75, 1.0)), _color(rng, (0.3, 0.8), (0.5, 0.95))
    clouds = Material(pattern="noise", colors=[zenith, [1.0, 1.0, 1.0]], frequency=1.5 / radius,
                      noise_seed=int(rng.integers(0, 2**31 - 1)), grain=0.0, emissive=True)
    return Material(pattern="gradient", colors=[horizon, horizon, zenith], direction=[0.0, 0.0, 1.0],
                    extent=radius * 0.5, offset=[0.0, 0.0, -radius * 0.5], emissive=True,
                    noise_seed=int(rng.integers(0, 2**31 - 1)), noise_frequency=0.8 / radius, grain=0.0,
                    secondary=clouds)


# --------------------------------------------------------------------------------------------------
# Cameras


def look_at(position: np.ndarray, target: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """Camera-to-world rotation (OpenCV axes) looking from position at target, z up, with roll (rad)."""
    forward = target - position
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:  # looking straight up or down
        right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward], 1)
    return rot @ rotation_about_axis([0.0, 0.0, 1.0], roll)


class _Sinusoids:
    """A smooth random signal: sum of a few sinusoids per output dimension."""

    def __init__(self, rng, dims: int, amplitude: float, freq: tuple[float, float], count: int = 3):
        self.amp = amplitude * rng.uniform(0.3, 1.0, size=(count, dims)) / math.sqrt(count)
        self.freq = rng.uniform(*freq, size=(count, dims))
        self.phase = rng.uniform(0, 2 * math.pi, size=(count, dims))

    def __call__(self, tau: np.ndarray) -> np.ndarray:
        tau = np.asarray(tau, dtype=np.float64)[..., None, None]
        return np.sum(self.amp * np.sin(2 * math.pi * self.freq * tau + self.phase), axis=-2)


class _CameraPath:
    """Camera centre, orientation and focal scale as functions of time (seconds)."""

    def __init__(self, rng, kind: str, start: np.ndarray, target: np.ndarray, speed: float, shake: bool,
                 zoom: float, duration: float):
        self.kind, self.start, self.target, self.speed = kind, start, target, speed
        self.duration = max(duration, 1e-9)
        self.zoom = zoom
        offset = start - target
        self.radius = float(np.hypot(offset[0], offset[1]))
        self.angle0 = math.atan2(offset[1], offset[0])
        fwd = target - start
        self.forward_h = np.array([fwd[0], fwd[1], 0.0]) / max(np.hypot(fwd[0], fwd[1]), 1e-9)
        self.right_h = np.cross(self.forward_h, [0.0, 0.0, 1.0])
        self.sign = float(rng.choice([-1.0, 1.0]))
        self.pitch_wobble = _Sinusoids(rng, 1, 0.15, (0.05, 0.3))
        self.wander = _Sinusoids(rng, 3, 1.0, (0.05, 0.25))
        self.look_wander = _Sinusoids(rng, 3, 1.0, (0.05, 0.3))
        self.shake_pos = _Sinusoids(rng, 3, rng.uniform(0.005, 0.02), (1.0, 3.5), 4) if shake else None
        self.shake_rot = _Sinusoids(rng, 3, math.radians(rng.uniform(0.2, 0.8)), (1.0, 3.5), 4) if shake else None
        self.roll = float(rng.normal(0.0, math.radians(2.0)))
        if kind == "walk":  # drawn last, so the other kinds' paths keep their random streams
            self.heading = _Sinusoids(rng, 1, math.radians(rng.uniform(35.0, 70.0)), (0.03, 0.12))

    def centre_and_target(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        k, s = self.kind, self.speed * self.sign
        if k == "orbit":
            angle = self.angle0 + s * tau  # speed is angular here (rad/s)
            c = self.target + np.array([self.radius * math.cos(angle), self.radius * math.sin(angle),
                                        self.start[2] - self.target[2]])
            return c, self.target
        if k == "forward":
            c = self.start + abs(s) * tau * self.forward_h
            yaw = 0.15 * self.sign * tau
            d = rotation_about_axis([0.0, 0.0, 1.0], yaw) @ (self.target - self.start)
            return c, c + d + np.array([0.0, 0.0, self.pitch_wobble(tau)[0]])
        if k == "pan":
            d = rotation_about_axis([0.0, 0.0, 1.0], s * tau) @ (self.target - self.start)
            return self.start, self.start + d + np.array([0.0, 0.0, self.pitch_wobble(tau)[0]])
        if k == "truck":
            return self.start + s * tau * self.right_h, self.target
        if k == "handheld":
            return self.start + self.speed * self.wander(tau), self.target + 0.3 * self.look_wander(tau)
        if k == "walk":  # speed is the wander's scale (m); the height changes five times less than the floor position
            c = self.start + self.speed * self.wander(tau) * np.array([1.0, 1.0, 0.2])
            d = rotation_about_axis([0.0, 0.0, 1.0], self.heading(tau)[0]) @ (self.target - self.start)
            return c, c + d + np.array([0.0, 0.0, self.pitch_wobble(tau)[0]])
        return self.start, self.target  # static

    def centre(self, tau: float) -> np.ndarray:
        """Camera centre only (cheaper than ``pose``: used by the scene's placement checks)."""
        c = self.centre_and_target(tau)[0]
        return c + self.shake_pos(tau) if self.shake_pos is not None else c

    def pose(self, tau: float) -> np.ndarray:
        c, g = self.centre_and_target(tau)
        rot = look_at(c, g, self.roll)
        if self.shake_pos is not None:
            c = c + self.shake_pos(tau)
            a = self.shake_rot(tau)
            rot = rot @ rotation_about_axis([1, 0, 0], a[0]) @ rotation_about_axis([0, 1, 0], a[1]) \
                @ rotation_about_axis([0, 0, 1], a[2])
        return rigid(rot, c)

    def focal_scale(self, tau: float) -> float:
        s = min(max(tau / self.duration, 0.0), 1.0)
        return float(self.zoom ** (s * s * (3 - 2 * s)))


def _camera_speed(rng, kind: str) -> float:
    """Typical speed of each kind of motion: rad/s for orbit and pan, the wander's scale (m) for walk, m/s
    otherwise."""
    speeds = {  # every entry is drawn whatever the kind: the random stream of existing seeds depends on it
        "orbit": math.radians(rng.uniform(8, 30)),
        "forward": rng.uniform(0.3, 1.1),
        "pan": math.radians(rng.uniform(8, 35)),
        "truck": rng.uniform(0.25, 0.9),
        "handheld": rng.uniform(0.15, 0.45),
        "static": 0.0,
    }
    return float(rng.uniform(0.6, 1.5)) if kind == "walk" else speeds[kind]


# --------------------------------------------------------------------------------------------------
# Bodies and their motion


class _Motion:
    """Rigid motion of one body: p(tau) = p_ref + v (tau - tau_ref) + a sin(2 pi f tau + phi),
    R(tau) = Rot(axis, w (tau - tau_ref)) R0."""

    def __init__(self, position, rotation, tau_ref=0.0, velocity=None, axis=None, angular=0.0, osc=None):
        self.p, self.r0, self.tau_ref = np.asarray(position, float), np.asarray(rotation, float), tau_ref
        self.v = np.zeros(3) if velocity is None else np.asarray(velocity, float)
        self.axis, self.w = (np.array([0.0, 0.0, 1.0]) if axis is None else np.asarray(axis, float)), angular
        self.osc = osc  # (amplitude vector, frequency, phase) or None

    @property
    def moving(self) -> bool:
        return bool(np.any(self.v != 0) or self.w != 0 or self.osc is not None)

    def position(self, tau):
        tau = np.asarray(tau, dtype=np.float64)
        p = self.p + (tau - self.tau_ref)[..., None] * self.v
        if self.osc is not None:
            amp, f, phi = self.osc
            p = p + np.sin(2 * math.pi * f * tau + phi)[..., None] * amp
        return p

    def pose(self, tau: float) -> np.ndarray:
        rot = rotation_about_axis(self.axis, self.w * (tau - self.tau_ref)) @ self.r0
        return rigid(rot, self.position(tau))


def _random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _random_shape(rng) -> tuple[str, list[float], float]:
    shape = str(rng.choice(OBJECT_SHAPES, p=[0.3, 0.3, 0.22, 0.18]))
    size = float(np.exp(rng.uniform(np.log(0.15), np.log(0.65))))
    if shape == "sphere":
        aspect = [1.0, 1.0, 1.0] if rng.uniform() < 0.6 else rng.uniform(0.6, 1.5, size=3).tolist()
    elif shape == "box":
        aspect = np.exp(rng.uniform(np.log(0.3), np.log(1.8), size=3)).tolist()
    else:
        r = rng.uniform(0.5, 1.2)
        aspect = [r, r, rng.uniform(0.6, 1.8)]
    half = [size * a for a in aspect]
    r_top = float(rng.uniform(0.0, 0.7)) if shape == "cone" else 0.0
    return shape, half, r_top


class _Placement:
    """Scene-wide constraints: bodies stay in the room, away from the camera path and each other."""

    def __init__(self, room_half: np.ndarray | None, height: float, cam_centres: np.ndarray, taus: np.ndarray):
        self.room_half, self.height, self.cam, self.taus = room_half, height, cam_centres, taus
        self.room = None if room_half is None else (room_half[:2], height)
        self.accepted: list[tuple[np.ndarray, float]] = []  # (centres over taus, radius)

    def ok(self, centres: np.ndarray, radius: float, resting: bool) -> bool:
        if np.min(np.linalg.norm(centres - self.cam, axis=1)) < radius + 0.4:
            return False
        if self.room_half is not None:
            inside = np.all(np.abs(centres[:, :2]) <= self.room_half[:2] - radius - 0.05)
            if not inside or (not resting and np.max(centres[:, 2]) > self.height - radius - 0.05):
                return False
        for other, r in self.accepted:
            if np.min(np.linalg.norm(centres - other, axis=1)) < radius + r + 0.02:
                return False
        return True

    def accept(self, centres: np.ndarray, radius: float) -> None:
        self.accepted.append((centres, radius))


def _point_in_view(rng, cam_pose: np.ndarray, focal: float, height: int, width: int, depth_range,
                   room: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """A random world point that the camera sees, at a random depth (inside the room, if any)."""
    x = rng.uniform(0.1, 0.9) * width - 0.5
    y = rng.uniform(0.15, 0.9) * height - 0.5
    ray = np.array([(x - (width - 1) / 2) / focal, (y - (height - 1) / 2) / focal, 1.0])
    lo, hi = depth_range
    if room is not None:
        hi = min(hi, 0.85 * _exit_depth(cam_pose, ray, *room))
    z = rng.uniform(lo, max(lo, hi))
    return cam_pose[:3, :3] @ (ray * z) + cam_pose[:3, 3]


def _exit_depth(cam_pose: np.ndarray, ray_cam: np.ndarray, half_xy: np.ndarray, ceiling: float) -> float:
    """Depth (camera z) at which a camera ray leaves the room box [-hx, hx] x [-hy, hy] x [0, ceiling]."""
    o, d = cam_pose[:3, 3], cam_pose[:3, :3] @ ray_cam
    lo, hi = np.array([-half_xy[0], -half_xy[1], 0.0]), np.array([half_xy[0], half_xy[1], ceiling])
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf))
    return float(max(t.min(), 0.0))


def _sample_object_motion(rng, shape_info, placement: _Placement, camera: _CameraPath, focal: float,
                          height: int, width: int, duration: float, moving_fraction: float, max_depth: float,
                          attempts: int = 40):
    shape, half, r_top = shape_info
    radius = float(np.linalg.norm(half))
    floor_z = placement.height if placement.room_half is not None else 4.0
    for attempt in range(attempts):
        moving = rng.uniform() < moving_fraction and attempt < attempts - 10
        crossing = moving and rng.uniform() < 0.35  # enters or leaves the view during the clip
        tau_ref = rng.uniform(0, duration) if crossing else 0.0
        cam_ref = camera.pose(tau_ref)
        p = _point_in_view(rng, cam_ref, focal * camera.focal_scale(tau_ref), height, width, (1.2, max_depth),
                           placement.room)
        resting = rng.uniform() < 0.5
        if resting:
            rot0 = rotation_about_axis([0, 0, 1], rng.uniform(0, 2 * math.pi))
            p[2] = half[2]
        else:
            rot0 = _random_rotation(rng)
            p[2] = float(np.clip(p[2], radius + 0.05, max(radius + 0.05, floor_z - radius - 0.1)))
        velocity, axis, angular, osc = None, None, 0.0, None
        if moving:
            if crossing:
                right = cam_ref[:3, 0] * np.array([1.0, 1.0, 0.0])
                direction = right / max(np.linalg.norm(right), 1e-9) * rng.choice([-1.0, 1.0])
                speed = rng.uniform(0.8, 2.0)
            else:
                direction = np.array([*rng.normal(size=2), 0.0])
                direction /= max(np.linalg.norm(direction), 1e-9)
                speed = rng.uniform(0.15, 1.2)
            velocity = direction * speed
            if not resting:
                velocity[2] = rng.uniform(-0.2, 0.2)
            if resting:
                axis, angular = np.array([0.0, 0.0, 1.0]), math.radians(rng.uniform(-90, 90))
            else:
                axis, angular = np.array(_unit(rng)), math.radians(rng.uniform(20, 150)) * rng.choice([-1, 1])
            if rng.uniform() < 0.3:
                d = np.array([*rng.normal(size=2), 0.0 if resting else rng.normal()])
                osc = (d / np.linalg.norm(d) * rng.uniform(0.1, 0.4), rng.uniform(0.3, 1.0), rng.uniform(0, 2 * math.pi))
        motion = _Motion(p, rot0, tau_ref, velocity, axis, angular, osc)
        centres = motion.position(placement.taus)
        if placement.ok(centres, radius, resting):
            placement.accept(centres, radius)
            return motion
    return None


def _arm(rng, placement: _Placement, camera: _CameraPath, focal, height, width, max_depth):
    """An articulated arm: a base cylinder and two box links on hinge joints, each part a rigid body
    with its own id. Returns [(Body, pose function, kind)], or [] if it does not fit in the scene."""
    base_r, base_h = rng.uniform(0.12, 0.2), rng.uniform(0.15, 0.35)
    l1, l2 = rng.uniform(0.22, 0.4), rng.uniform(0.18, 0.32)
    w1, w2 = rng.uniform(0.05, 0.08), rng.uniform(0.04, 0.06)
    joint1 = (rng.uniform(-0.6, 0.6), math.radians(rng.uniform(20, 60)), rng.uniform(0.3, 1.0), rng.uniform(0, 6.3))
    joint2 = (rng.uniform(-1.0, 1.0), math.radians(rng.uniform(20, 70)), rng.uniform(0.3, 1.2), rng.uniform(0, 6.3))

    def angle(j, tau):
        return j[0] + j[1] * math.sin(2 * math.pi * j[2] * tau + j[3])

    def hinge(offset, length, theta):
        # From the parent's frame: up to the joint, rotate about the local x axis, out to the link's centre.
        return rigid(np.eye(3), [0, 0, offset]) @ rigid(rotation_about_axis([1, 0, 0], theta), [0, 0, 0]) \
            @ rigid(np.eye(3), [0, 0, length])

    parts = [
        Body("cylinder", [base_r, base_r, base_h], [random_material(rng, "object", base_h)], name="arm_base"),
        Body("box", [w1, w1, l1], [random_material(rng, "object", l1)], name="arm_link1"),
        Body("box", [w2, w2, l2], [random_material(rng, "object", l2)], name="arm_link2"),
    ]
    for _ in range(30):
        cam0 = camera.pose(0.0)
        p = _point_in_view(rng, cam0, focal * camera.focal_scale(0.0), height, width, (2.0, max_depth),
                           placement.room)
        p[2] = base_h
        yaw_rate = math.radians(rng.uniform(-40, 40)) if rng.uniform() < 0.6 else 0.0
        base = _Motion(p, rotation_about_axis([0, 0, 1], rng.uniform(0, 2 * math.pi)), 0.0, None,
                       np.array([0.0, 0.0, 1.0]), yaw_rate)

        def pose_link1(tau, base=base):
            return base.pose(tau) @ hinge(base_h, l1, angle(joint1, tau))

        def pose_link2(tau, pose_link1=pose_link1):
            return pose_link1(tau) @ hinge(l1, l2, angle(joint2, tau))

        fns = [base.pose, pose_link1, pose_link2]
        centres = [np.array([fn(t)[:3, 3] for t in placement.taus]) for fn in fns]
        if all(placement.ok(c, part.bounding_radius, resting=False) for c, part in zip(centres, parts)):
            for c, part in zip(centres, parts):
                placement.accept(c, part.bounding_radius)
            return list(zip(parts, fns, ["arm_base", "arm_link1", "arm_link2"]))
    return []


# --------------------------------------------------------------------------------------------------


def sample_scene(seed: int, frames: int, height: int, width: int, options: SceneOptions | None = None) -> SampledScene:
    """Draw a random dynamic scene and evaluate its cameras and body poses at every frame."""
    options = options or SceneOptions()
    options.validate()
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise UserError(f"seed must be a non-negative integer, got {seed!r}")
    if frames < 1 or height < 1 or width < 1:
        raise UserError(f"frames, height and width must be positive, got {frames}, {height}, {width}")
    rng = np.random.default_rng(int(seed))
    duration = (frames - 1) * options.time_stride / options.fps
    taus = np.linspace(0.0, duration, max(2, 4 * frames))

    env_kind = options.environment or str(rng.choice(["room", "outdoor"], p=[0.6, 0.4]))
    cam_kind = options.camera_motion or str(rng.choice(MOVING_CAMERA_MOTIONS))
    if options.camera_motion is None and options.walk_fraction > 0 and rng.uniform() < options.walk_fraction:
        cam_kind = "walk"
    shake = bool(rng.uniform() < 0.5) if options.shake is None else options.shake
    do_zoom = bool(rng.uniform() < 0.25) if options.zoom is None else options.zoom
    zoom = float(np.exp(rng.uniform(-1, 1) * math.log(1.5))) if do_zoom else 1.0
    fov = math.radians(rng.uniform(*options.fov_degrees))
    focal = (max(height, width) / 2.0) / math.tan(fov / 2.0)

    # Environment and camera path (retried with gentler motion until the camera stays inside).
    if env_kind == "room":
        room_half = np.array([rng.uniform(2.5, 5.0), rng.uniform(2.5, 5.0)])
        ceiling = rng.uniform(2.6, 4.0)
        env = Body("room", [room_half[0], room_half[1], ceiling / 2],
                   [random_material(rng, "wall", 3.0), random_material(rng, "wall", 3.0),
                    random_material(rng, "wall", 3.0), random_material(rng, "wall", 3.0),
                    random_material(rng, "floor", 3.0), random_material(rng, "ceiling", 3.0)], name="room")
        env_pose = rigid(np.eye(3), [0.0, 0.0, ceiling / 2])
        room_box = np.array([room_half[0], room_half[1]])
        max_depth = 0.9 * float(np.min(room_half)) * 2
    else:
        radius = 60.0
        ceiling, room_box = 8.0, None
        env = Body("outdoor", [radius, radius, radius], [random_material(rng, "ground", 10.0),
                                                        _sky_material(rng, radius)], name="outdoor")
        env_pose = np.eye(4)
        max_depth = 9.0

    speed = _camera_speed(rng, cam_kind)
    camera = None
    for attempt in range(8):
        if room_box is not None:
            start = np.array([*(rng.uniform(-1, 1, 2) * (room_box - 1.3)), rng.uniform(1.0, 1.9)])
        else:
            start = np.array([*rng.uniform(-3, 3, 2), rng.uniform(1.0, 2.5)])
        yaw = rng.uniform(0, 2 * math.pi)
        dist = rng.uniform(3.0, 6.0)
        if room_box is not None:  # aim inside the room, towards its larger open side
            yaw = math.atan2(-start[1], -start[0]) + rng.uniform(-0.8, 0.8)
            dist = min(dist, 0.8 * _distance_to_wall(start, yaw, room_box))
        target = start + np.array([dist * math.cos(yaw), dist * math.sin(yaw), 0.0])
        target[2] = rng.uniform(0.3, 1.2)
        camera = _CameraPath(rng, cam_kind, start, target, speed * 0.5**attempt, shake, zoom, duration)
        centres = np.array([camera.centre(t) for t in taus])
        if room_box is None or (np.all(np.abs(centres[:, :2]) <= room_box - 0.3)
                                and np.all((centres[:, 2] > 0.3) & (centres[:, 2] < ceiling - 0.3))):
            break
    else:
        camera = _CameraPath(rng, "static", start, target, 0.0, False, zoom, duration)
        cam_kind = "static"
    cam_centres = np.array([camera.centre(t) for t in taus])

    # Foreground bodies.
    placement = _Placement(None if room_box is None else np.array([*room_box, ceiling]), ceiling, cam_centres, taus)
    n_objects = int(rng.integers(3, 9)) if options.num_objects is None else options.num_objects
    with_arm = bool(rng.uniform() < 0.4) if options.articulated is None else options.articulated
    bodies, pose_fns, kinds = [env], [lambda tau: env_pose], ["environment"]
    if with_arm:
        for body, fn, kind in _arm(rng, placement, camera, focal, height, width, max_depth):
            body.parent = None if kind == "arm_base" else len(bodies) - 1
            bodies.append(body)
            pose_fns.append(fn)
            kinds.append(kind)
    for _ in range(n_objects):
        shape_info = _random_shape(rng)
        motion = _sample_object_motion(rng, shape_info, placement, camera, focal, height, width, duration,
                                       options.moving_fraction, max_depth)
        if motion is None:
            continue
        shape, half, r_top = shape_info
        extent = max(half)
        faces = {"sphere": 1, "box": int(rng.integers(1, 4)), "cylinder": int(rng.integers(1, 3)),
                 "cone": int(rng.integers(1, 3))}[shape]
        bodies.append(Body(shape, half, [random_material(rng, "object", extent) for _ in range(faces)],
                           r_top=r_top, name=shape))
        pose_fns.append(motion.pose)
        kinds.append("moving" if motion.moving else "static")

    # Light.
    if env_kind == "room":
        light = Light("point", color=[c * rng.uniform(2.0, 3.0) for c in _color(rng, (0.0, 0.25), (0.9, 1.0))],
                      ambient=[c * rng.uniform(0.25, 0.45) for c in _color(rng, (0.0, 0.2), (0.9, 1.0))],
                      position=[*(rng.uniform(-0.6, 0.6, 2) * room_box), ceiling - 0.2],
                      falloff=float(rng.uniform(4.0, 8.0)))
    else:
        elevation, azimuth = math.radians(rng.uniform(25, 70)), rng.uniform(0, 2 * math.pi)
        light = Light("directional", color=[c * rng.uniform(0.9, 1.3) for c in _color(rng, (0.0, 0.25), (0.9, 1.0))],
                      ambient=[c * rng.uniform(0.25, 0.45) for c in _color(rng, (0.0, 0.3), (0.9, 1.0))],
                      direction=[math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                                 math.sin(elevation)])

    # Per-frame cameras and poses.
    times = np.arange(frames) * options.time_stride / options.fps
    cam_to_world = np.stack([camera.pose(t) for t in times])
    object_to_world = np.stack([np.stack([fn(t) for fn in pose_fns]) for t in times])
    cx = (width - 1) / 2.0 + rng.uniform(-1, 1) * options.principal_point_jitter * width
    cy = (height - 1) / 2.0 + rng.uniform(-1, 1) * options.principal_point_jitter * height
    intrinsics = np.zeros((frames, 3, 3))
    for i, t in enumerate(times):
        f = focal * camera.focal_scale(t)
        intrinsics[i] = [[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]

    recorded = {k: v for k, v in asdict(options).items() if k not in _LATER_OPTIONS or v != _LATER_OPTIONS[k]}
    info = {"seed": int(seed), "options": recorded, "environment": env_kind, "camera_motion": cam_kind,
            "shake": shake, "zoom": zoom, "body_motion": kinds, "times": times.tolist()}
    description = SceneDescription(bodies, light, shadows=options.shadows, info=info)
    return SampledScene(description, intrinsics, cam_to_world, object_to_world)


def _distance_to_wall(start: np.ndarray, yaw: float, half: np.ndarray) -> float:
    d = np.array([math.cos(yaw), math.sin(yaw)])
    ts = []
    for i in range(2):
        if abs(d[i]) > 1e-9:
            ts.append(((half[i] if d[i] > 0 else -half[i]) - start[i]) / d[i])
    return float(max(min(ts), 0.5))
