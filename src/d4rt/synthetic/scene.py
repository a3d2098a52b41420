"""The static description of a synthetic scene: bodies (shape, size, materials), environment, light.

Motion is not part of the description: the per-frame poses live in the clip's ``object_to_world``
and ``cam_to_world`` arrays, which are the single source of truth for geometry. The description plus
those arrays is everything needed to ray-cast the scene again, exactly, for any pixel of any frame.
It is stored as JSON inside the clip's npz file (no pickles).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from d4rt.synthetic.shapes import ENVIRONMENTS, NUM_FACES, SHAPES

PATTERNS = ("solid", "noise", "marble", "stripes", "checker", "dots", "gradient")


@dataclass
class Material:
    """A procedural solid texture evaluated at points in the body's own (metric) frame.

    Colours are linear RGB in [0, 1]. ``frequency`` is in cycles per metre. ``secondary`` (optional)
    is blended in through a noise mask (a "mixture" texture). ``emissive`` surfaces (the sky) are not lit.
    """

    pattern: str
    colors: list[list[float]]
    frequency: float = 2.0
    direction: list[float] = field(default_factory=lambda: [1.0, 0.0, 0.0])
    offset: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    extent: float = 1.0
    noise_seed: int = 0
    noise_frequency: float = 2.0
    grain: float = 0.1
    specular: float = 0.0
    shininess: float = 16.0
    emissive: bool = False
    secondary: "Material | None" = None

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ValueError(f"unknown texture pattern {self.pattern!r}; expected one of {PATTERNS}")
        if isinstance(self.secondary, dict):
            self.secondary = Material(**self.secondary)


@dataclass
class Body:
    """One rigid body: a canonical primitive scaled by ``half_extents`` (metres, per local axis).

    ``materials[face % len(materials)]`` textures each face (see ``shapes.NUM_FACES``). ``parent`` is
    the id of the body this one is jointed to (articulated objects), or None.
    """

    shape: str
    half_extents: list[float]
    materials: list[Material]
    r_top: float = 0.0
    name: str = ""
    parent: int | None = None

    def __post_init__(self) -> None:
        if self.shape not in SHAPES + ENVIRONMENTS:
            raise ValueError(f"unknown shape {self.shape!r}")
        self.materials = [Material(**m) if isinstance(m, dict) else m for m in self.materials]
        if not self.materials:
            raise ValueError("a body needs at least one material")

    @property
    def bounding_radius(self) -> float:
        """Radius of a sphere about the body origin containing the whole body."""
        return float(sum(h * h for h in self.half_extents) ** 0.5)

    @property
    def num_faces(self) -> int:
        return NUM_FACES[self.shape]


@dataclass
class Light:
    """A directional light (``direction`` points from the scene towards the light) or a point light
    at ``position``; plus an ambient term. Colours are linear RGB."""

    kind: str
    color: list[float]
    ambient: list[float]
    direction: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 3.0])
    falloff: float = 6.0

    def __post_init__(self) -> None:
        if self.kind not in ("directional", "point"):
            raise ValueError(f"unknown light kind {self.kind!r}")


@dataclass
class SceneDescription:
    """``bodies[k]`` is the body with object id k; ``bodies[0]`` is the static environment."""

    bodies: list[Body]
    light: Light
    shadows: bool = True
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.bodies = [Body(**b) if isinstance(b, dict) else b for b in self.bodies]
        if isinstance(self.light, dict):
            self.light = Light(**self.light)
        if not self.bodies or self.bodies[0].shape not in ENVIRONMENTS:
            raise ValueError("bodies[0] must be the environment (room or outdoor)")
        if any(b.shape in ENVIRONMENTS for b in self.bodies[1:]):
            raise ValueError("only bodies[0] may be an environment")

    @property
    def num_bodies(self) -> int:
        return len(self.bodies)

    def to_json(self) -> str:
        return json.dumps(asdict(self), separators=(",", ":"), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "SceneDescription":
        return cls(**json.loads(text))
