"""Writers of tiny datasets in published on-disk layouts, for the reader and harness tests."""

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from d4rt.geometry.transforms import rigid

H, W = 8, 12
RNG = np.random.default_rng(0)


def write_png(path, array):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


def random_rgb(h=H, w=W):
    return RNG.integers(0, 256, (h, w, 3), dtype=np.uint8)


def random_poses(frames):
    rotations = Rotation.from_rotvec(RNG.normal(0, 0.3, (frames, 3))).as_matrix()
    return rigid(rotations, RNG.normal(0, 1, (frames, 3)))


def write_sintel(root, seq, frames):
    tag = np.array([202021.25], np.float32)
    depths = RNG.uniform(1, 100, (frames, H, W)).astype(np.float32)
    k = np.array([[30.0, 0, (W - 1) / 2], [0, 31.0, (H - 1) / 2], [0, 0, 1]])
    cam_to_world = random_poses(frames)
    for i in range(frames):
        stem = f"frame_{i + 1:04d}"
        (root / "training/depth" / seq).mkdir(parents=True, exist_ok=True)
        with open(root / "training/depth" / seq / f"{stem}.dpt", "wb") as f:
            f.write(tag.tobytes() + np.array([W, H], np.int32).tobytes() + depths[i].tobytes())
        (root / "training/camdata_left" / seq).mkdir(parents=True, exist_ok=True)
        world_to_cam = np.linalg.inv(cam_to_world[i])[:3]
        with open(root / "training/camdata_left" / seq / f"{stem}.cam", "wb") as f:
            f.write(tag.tobytes() + k.tobytes() + world_to_cam.tobytes())
        write_png(root / "training/final" / seq / f"{stem}.png", random_rgb())
    return depths, k, cam_to_world


def write_re10k(root, seq, frames, h=H, w=W):
    """A RealEstate10K camera file (URL line, then timestamp, normalised fx fy cx cy, two zeros, 3x4
    world-to-camera) and its extracted frames named by timestamp. Returns (timestamps, K (3, 3) in pixels,
    cam_to_world (frames, 4, 4))."""
    cam_to_world = random_poses(frames)
    stamps = 1_000_000 + 33_367 * np.arange(frames)
    k = np.array([[0.9 * w, 0, 0.5 * w - 0.5], [0, 1.6 * h, 0.5 * h - 0.5], [0, 0, 1]])
    lines = [f"https://www.youtube.com/watch?v={seq}"]
    for stamp, pose in zip(stamps, cam_to_world):
        world_to_cam = np.linalg.inv(pose)[:3].reshape(-1)
        lines.append(" ".join([str(stamp), "0.9", "1.6", "0.5", "0.5", "0", "0", *(f"{v:.17g}" for v in world_to_cam)]))
        write_png(root / seq / f"{stamp}.png", random_rgb(h, w))
    (root / f"{seq}.txt").write_text("\n".join(lines) + "\n")
    return stamps, k, cam_to_world
