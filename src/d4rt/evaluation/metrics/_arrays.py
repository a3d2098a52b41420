"""Input handling shared by the metric functions: numpy or torch in, float64 numpy out, shapes checked."""

from __future__ import annotations

import numpy as np
import torch

from d4rt.errors import UserError


def as_array(value, name: str, dtype=np.float64) -> np.ndarray:
    """A numpy copy-free view (when possible) of a numpy array, torch tensor or nested sequence."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise UserError(f"{name} must be a numeric array, got {type(value).__name__}: {err}") from None


def check_shape(array: np.ndarray, name: str, shape: tuple) -> None:
    """Raise unless ``array.shape`` matches ``shape``, where None entries match any size."""
    ok = array.ndim == len(shape) and all(want is None or got == want for got, want in zip(array.shape, shape))
    if not ok:
        pattern = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise UserError(f"{name} must have shape {pattern}, got {tuple(array.shape)}")


def check_same_shape(a: np.ndarray, b: np.ndarray, name_a: str, name_b: str) -> None:
    if a.shape != b.shape:
        raise UserError(f"{name_a} {tuple(a.shape)} and {name_b} {tuple(b.shape)} must have the same shape")


def check_finite(array: np.ndarray, name: str, where: np.ndarray | None = None) -> None:
    """Raise if ``array`` (restricted to the boolean mask ``where``, if given) holds NaN or infinity."""
    values = array if where is None else array[where]
    bad = int((~np.isfinite(values)).sum())
    if bad:
        scope = "" if where is None else " where it is evaluated"
        raise UserError(f"{name} has {bad} NaN or infinite values{scope}")
