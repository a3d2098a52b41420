"""The offline HTML viewer: self-contained, and headless Chromium loads it without a console message and
draws the scene (a screenshot with many non-background pixels)."""

import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

from d4rt.io.exports import export_reconstruction
from d4rt.synthetic import render_clip
from subprocess_budget import budget

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
BACKGROUND = (0x14, 0x16, 0x1A)  # the page's background colour


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    clip = render_clip(4, 4, 30, 40, environment="room", num_objects=3, camera_motion="orbit")
    out = tmp_path_factory.mktemp("viewer") / "out"
    export_reconstruction(clip.reconstruction(), out, ["html"], track_grid=4)
    return out / "viewer.html"


def test_page_is_self_contained(page):
    text = page.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text), "the page must not load anything"
    assert "fetch(" not in text and "XMLHttpRequest" not in text and "console." not in text


def _chromium(*args, timeout=budget(120)):
    return subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=800,600",
                           "--virtual-time-budget=2000", *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (.ci/run installs Debian's chromium)")
def test_chromium_loads_and_draws_it(page, tmp_path):
    shot = tmp_path / "shot.png"
    run = _chromium("--enable-logging=stderr", "--v=0", f"--screenshot={shot}", page.as_uri())
    console = [line for line in run.stderr.splitlines() if "CONSOLE" in line]
    assert console == [], console  # the viewer prints nothing, so any console line is an error
    pixels = np.asarray(Image.open(shot).convert("RGB"))[30:520]  # below the help line, above the controls
    drawn = np.abs(pixels.astype(int) - BACKGROUND).sum(-1) > 30
    assert pixels.shape[1] == 800 and drawn.mean() > 0.01, drawn.mean()
    dom = _chromium("--dump-dom", page.as_uri()).stdout
    status = re.search(r'data-status="([^"]*)"', dom).group(1)
    drawn_points = int(re.search(r'data-drawn-points="(\d+)"', dom).group(1))
    assert status == "ready" and drawn_points > 500, (status, drawn_points)
