"""``synthetic-dynamic-v1``: a fixed, versioned benchmark of synthetic dynamic clips with exact ground truth.

48 clips of 24 frames. Clip i (i = 0..47) is ``render_clip(seed=BASE_SEED + i, frames=24, height, width,
**options)`` with, deterministically from i:

- size (H, W) = SIZES[i % 6]: 128x128 (1:1), 120x160 (4:3), 108x192 (16:9), 96x192 (2:1), 160x120 (3:4),
  192x108 (9:16);
- field of view across the longer side drawn in FOV_BANDS[i // 6]: 30-40, 40-50, ..., 100-110 degrees
  (focal lengths from about 0.35x to 1.4x the longer side);
- camera_motion = MOVING_CAMERA_MOTIONS[i % 5] (orbit, forward, pan, truck, handheld: the camera always
  moves; pans get hand-held shake so that every camera also translates, which pose AUC's translation
  directions need); environment room / outdoor alternating in pairs; zoom for every fourth clip;
- num_objects = 4 + i % 5 rigid objects, each moving with probability 0.8 (``moving_fraction``), so
  objects move, occlude each other and enter or leave the view; everything else (shapes, textures,
  light, speeds, shake) is drawn from the seed.
- 256 ground-truth 3D tracks per clip from the exact oracle (``readers.synthetic.oracle_tracks``, track
  seed = clip seed).

The same definition regenerates the same clips bit for bit on the same device; ``SCENE_FINGERPRINT``
freezes the definition on any CPU: if scene sampling ever changes, the fingerprint test fails and the
benchmark needs a new version instead of silently changing. The version is in the name. It is two parts
(``scene_fingerprint``): a hash of everything in the scenes that is not a floating-point number (keys,
strings, integers, flags, array shapes), and two sums of all their floating-point numbers (description,
cameras, body poses), compared to within 1e-7. Why not one hash of the numbers: their last bits depend on
the CPU's BLAS and SIMD kernels (an AVX2 machine and an AVX-512 one hash them differently; two OpenBLAS
kernels on one machine move the sums by about 2e-10), while any one number changed by more than 1e-7
moves the sums by as much.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers.synthetic import NUM_TRACKS, sequence_from_clip
from d4rt.evaluation.sequence import EvalSequence
from d4rt.synthetic.generate import render_clip
from d4rt.synthetic.sampling import MOVING_CAMERA_MOTIONS, SceneOptions, sample_scene

NAME = "synthetic-dynamic-v1"
NUM_CLIPS = 48
FRAMES = 24
BASE_SEED = 20_251_000
SIZES = ((128, 128), (120, 160), (108, 192), (96, 192), (160, 120), (192, 108))
FOV_BANDS = tuple((float(lo), float(lo + 10)) for lo in range(30, 110, 10))


@dataclass(frozen=True)
class SyntheticClipSpec:
    """Everything that determines one clip of the benchmark."""

    index: int
    seed: int
    height: int
    width: int
    options: SceneOptions

    @property
    def name(self) -> str:
        return f"clip_{self.index:02d}"

    def render(self, device: str = "cpu") -> EvalSequence:
        """Render the clip and attach its oracle tracks."""
        clip = render_clip(self.seed, FRAMES, self.height, self.width, device=device, **vars(self.options))
        return sequence_from_clip(clip, self.name, NUM_TRACKS, track_seed=self.seed)


def clip_specs() -> list[SyntheticClipSpec]:
    """The 48 clip definitions, in order."""
    specs = []
    for i in range(NUM_CLIPS):
        options = SceneOptions(
            environment=("room", "outdoor")[(i // 2) % 2],
            num_objects=4 + i % 5,
            camera_motion=MOVING_CAMERA_MOTIONS[i % len(MOVING_CAMERA_MOTIONS)],
            fov_degrees=FOV_BANDS[i // len(SIZES)],
            zoom=i % 4 == 3,
            shake=True if MOVING_CAMERA_MOTIONS[i % len(MOVING_CAMERA_MOTIONS)] == "pan" else None,
            moving_fraction=0.8,
        )
        specs.append(SyntheticClipSpec(i, BASE_SEED + i, *SIZES[i % len(SIZES)], options))
    return specs


# Gate sets (docs/training.md, "Gate sets drawn per judgment"): the 48 definitions drawn from seeds GATE_SEED + index,
# for one ship judgment each. A range no benchmark, probe or training stream draws from (probes use 6-9 and 12-13
# million, the benchmark 20,251,000 + index; training clips take random 31-bit seeds).
GATE_SEEDS = range(11_000_000, 12_000_000 - NUM_CLIPS + 1)


def gate_specs(gate_seed: int) -> list[SyntheticClipSpec]:
    """The 48 clip definitions with clip i's seed replaced by ``gate_seed`` + i (a judge's gate set)."""
    if gate_seed not in GATE_SEEDS:
        raise UserError(f"a gate seed must lie in {GATE_SEEDS.start:,}-{GATE_SEEDS.stop - 1:,} (no other stream draws "
                        f"from there), got {gate_seed:,}")
    return [replace(spec, seed=gate_seed + spec.index) for spec in clip_specs()]


@dataclass(frozen=True)
class SceneFingerprint:
    """What freezes the scenes: ``structure``, a sha256 of every non-float part; ``sums``, the plain sum of every
    float and the sum weighted by position (which catches values that trade places)."""

    structure: str
    sums: tuple[float, float]

    def matches(self, other: "SceneFingerprint", atol: float = 1e-7) -> bool:
        """Same structure exactly, and sums within ``atol`` (CPU-dependent rounding moves them by about 2e-10)."""
        return self.structure == other.structure and bool(np.allclose(self.sums, other.sums, rtol=0.0, atol=atol))


# synthetic-dynamic-v1's scenes. Until 2026-11-25 one hash of every number (0cf87ee8...) froze them; an AVX2 CPU's
# rounding changed that hash, so these values were computed on it (the shipped model's fixed-clip figures still agree).
SCENE_FINGERPRINT = SceneFingerprint("d9f38f1f2bc5b2491a238e2baa4e9962aa5bf6142e4b75d2ea6626881ca7c1f4",
                                     (561646.2176199557, 858443.3375195428))


def _split(value, floats: list[float]):
    """``value`` (parsed JSON) with every float moved to ``floats`` and replaced by a placeholder."""
    if isinstance(value, float):
        floats.append(value)
        return "<float>"
    if isinstance(value, dict):
        return {key: _split(item, floats) for key, item in value.items()}
    if isinstance(value, list):
        return [_split(item, floats) for item in value]
    return value


def scene_fingerprint(specs: list[SyntheticClipSpec] | None = None) -> SceneFingerprint:
    """The fingerprint of every clip's sampled scene (description JSON, intrinsics, poses, body poses)."""
    digest, parts = hashlib.sha256(), []
    for spec in specs or clip_specs():
        scene = sample_scene(spec.seed, FRAMES, spec.height, spec.width, spec.options)
        floats: list[float] = []
        digest.update(json.dumps(_split(json.loads(scene.description.to_json()), floats), sort_keys=True).encode())
        parts.append(np.asarray(floats, dtype=np.float64))
        for array in (scene.intrinsics, scene.cam_to_world, scene.object_to_world):
            digest.update(str(np.shape(array)).encode())
            parts.append(np.asarray(array, dtype=np.float64).ravel())
    values = np.concatenate(parts)
    weights = 1.0 + np.arange(values.size) % 997 / 997.0
    return SceneFingerprint(digest.hexdigest(), (float(values.sum()), float((values * weights).sum())))
