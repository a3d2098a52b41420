"""Shared fixture of the training tests: small synthetic clips on disk."""

from __future__ import annotations

from pathlib import Path

import pytest

from d4rt.synthetic import render_clip


@pytest.fixture(scope="session")
def clip_dir(tmp_path_factory) -> Path:
    """A directory with two small clips (4 frames, 32x32) in the ``d4rt generate`` layout."""
    directory = tmp_path_factory.mktemp("clips")
    for seed in (7, 8):
        render_clip(seed, 4, 32, 32, num_objects=2).save(directory / f"clip_{seed}.npz")
    return directory

