"""Procedural solid textures, band-limited to the pixel footprint (texture anti-aliasing).

A texture is evaluated at points in its body's own metric frame, so it moves rigidly with the body.
``footprint`` is the width of one pixel on the surface (metres); each pattern is filtered over that
width analytically: sinusoids are attenuated by their Gaussian transfer exp(-2 pi^2 f^2 w^2), square
waves (stripes, checkers) are box-filtered exactly through their integral (a triangle wave), and
patterns whose period falls below the footprint fade to their mean colour. Geometric edges are
anti-aliased separately by supersampling (render.py).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from d4rt.synthetic.scene import Material

NOISE_COMPONENTS = 8  # sinusoids per noise; the fine "grain" noise uses half as many


@functools.lru_cache(maxsize=4096)
def _noise_table(seed: int, base_frequency: float, components: int) -> tuple[tuple[float, ...], ...]:
    """Random sinusoid components (direction xyz, frequency, phase, amplitude), one row each."""
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(components, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freqs = base_frequency * 2.0 ** (np.arange(components) * 0.55 + rng.uniform(0, 0.5, components))
    phases = rng.uniform(0, 2 * math.pi, components)
    amps = freqs ** -0.8
    amps /= np.sqrt(np.sum(amps**2) / 2.0) * 2.0  # about 2 standard deviations span [-1, 1]
    return tuple(map(tuple, np.concatenate([dirs, freqs[:, None], phases[:, None], amps[:, None]], 1).tolist()))


def noise(points: torch.Tensor, footprint: torch.Tensor, seed: int, frequency: float,
          components: int = NOISE_COMPONENTS) -> torch.Tensor:
    """Smooth band-limited noise in about [-1, 1]. points: (M, 3); footprint: (M,) -> (M,)."""
    table = _noise_table(seed, frequency, components)
    out = torch.zeros_like(footprint)
    w2 = footprint * footprint
    for dx, dy, dz, f, phase, amp in table:
        arg = (points[:, 0] * dx + points[:, 1] * dy + points[:, 2] * dz) * (2 * math.pi * f) + phase
        out += torch.sin(arg) * (amp * torch.exp(w2 * (-2 * math.pi**2 * f * f)))
    return out


def _triangle(x: torch.Tensor) -> torch.Tensor:
    """Integral of the +-1 square wave of period 1 (+1 on [0, 0.5)): 0.5 - |frac(x) - 0.5|."""
    return 0.5 - (x - torch.floor(x) - 0.5).abs()


def square_wave(x: torch.Tensor, width: torch.Tensor) -> torch.Tensor:
    """The +-1 square wave of period 1, box-filtered over ``width`` (same units as x)."""
    w = torch.clamp(width, min=1e-4)
    return (_triangle(x + 0.5 * w) - _triangle(x - 0.5 * w)) / w


def _smoothstep(edge0: float | torch.Tensor, edge1: float | torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    t = torch.clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _lerp_colors(colors: list[list[float]], weight: torch.Tensor) -> torch.Tensor:
    """Blend colours[0] -> colours[1] by weight in [0, 1]. weight: (M,) -> (M, 3)."""
    c0 = torch.tensor(colors[0], dtype=weight.dtype, device=weight.device)
    c1 = torch.tensor(colors[1 % len(colors)], dtype=weight.dtype, device=weight.device)
    return c0 + (c1 - c0) * weight[:, None]


def albedo(material: Material, points: torch.Tensor, footprint: torch.Tensor) -> torch.Tensor:
    """Linear-RGB albedo of ``material`` at ``points`` (M, 3) with pixel ``footprint`` (M,) -> (M, 3)."""
    base = _pattern(material, points, footprint)
    if material.secondary is not None:
        mask = _smoothstep(-0.25, 0.25, noise(points, footprint, material.noise_seed + 1, material.noise_frequency))
        base = base + (_pattern(material.secondary, points, footprint) - base) * mask[:, None]
    if material.grain > 0:
        grain = noise(points, footprint, material.noise_seed + 2, material.noise_frequency * 4.0,
                      NOISE_COMPONENTS // 2)
        base = base * (1.0 + material.grain * grain)[:, None]
    return base.clamp(0.0, 1.0)


def _pattern(material: Material, points: torch.Tensor, footprint: torch.Tensor) -> torch.Tensor:
    m = material
    p = points + torch.tensor(m.offset, dtype=points.dtype, device=points.device)
    d = m.direction
    along = p[:, 0] * d[0] + p[:, 1] * d[1] + p[:, 2] * d[2]
    f = m.frequency
    if m.pattern == "solid":
        return _lerp_colors(m.colors, torch.zeros_like(footprint))
    if m.pattern == "noise":
        n = noise(p, footprint, m.noise_seed, f)
        return _lerp_colors(m.colors, _smoothstep(-0.7, 0.7, n))
    if m.pattern == "marble":
        n = noise(p, footprint, m.noise_seed, m.noise_frequency)
        wave = torch.sin(2 * math.pi * f * along + 4.0 * n) * torch.exp(footprint**2 * (-2 * math.pi**2 * f * f))
        return _lerp_colors(m.colors, 0.5 + 0.5 * wave)
    if m.pattern == "stripes":
        return _lerp_colors(m.colors, 0.5 + 0.5 * square_wave(f * along, f * footprint))
    if m.pattern == "checker":
        w = f * footprint
        q = square_wave(f * p[:, 0], w) * square_wave(f * p[:, 1], w) * square_wave(f * p[:, 2], w)
        return _lerp_colors(m.colors, 0.5 + 0.5 * q)
    if m.pattern == "dots":
        cell = f * p
        cell = cell - torch.floor(cell) - 0.5
        dist = cell.norm(dim=1)
        w = torch.clamp(f * footprint, min=1e-3)
        inside = 1.0 - _smoothstep(0.3 - w, 0.3 + w, dist)
        # Once dots shrink below a pixel, fade to their mean coverage (a sphere of radius 0.3 in a cell).
        fade = torch.clamp(2.0 * w - 0.5, 0.0, 1.0)
        coverage = 4.0 / 3.0 * math.pi * 0.3**3
        return _lerp_colors(m.colors, inside + (coverage - inside) * fade)
    if m.pattern == "gradient":
        ramp = torch.clamp(0.5 + 0.5 * along / m.extent, 0.0, 1.0)
        if len(m.colors) > 2:
            lower = _lerp_colors(m.colors[:2], torch.clamp(2 * ramp, 0, 1))
            upper = _lerp_colors(m.colors[1:3], torch.clamp(2 * ramp - 1, 0, 1))
            return torch.where((ramp < 0.5)[:, None], lower, upper)
        return _lerp_colors(m.colors, ramp)
    raise ValueError(f"unknown pattern {m.pattern!r}")
