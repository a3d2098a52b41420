"""`d4rt view`: the viser viewer of a reconstruction's output folder, opened in headless Chromium.

Every server binds to 127.0.0.1 on a free port and is stopped by the test."""

from __future__ import annotations

import io
import os
import shutil
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from d4rt.cli import main

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# Software WebGL: a headless browser on a machine without a GPU.
CHROMIUM_ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                 "--no-sandbox"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def output_folder(tmp_path_factory) -> Path:
    """The demo's synthetic output (every file d4rt reconstruct writes; the exact oracle answering, as the
    demo does without a model, so no model is needed)."""
    from d4rt.cli import demo

    out = tmp_path_factory.mktemp("view") / "synthetic"
    demo.run_synthetic(None, out)
    return out


def test_viewer_data_and_its_errors(output_folder, tmp_path):
    from d4rt.errors import UserError
    from d4rt.viz.viser_viewer import ViewerData, moving_tracks

    data = ViewerData.load(output_folder)
    assert data.num_frames == 24 and data.images.shape[0] == 24 and max(data.images.shape[1:3]) == 160
    assert len(data.points) == len(data.frames) == len(data.colors) and data.tracks.shape == (256, 24, 3)
    still = np.zeros((1, 4, 3))
    walking = np.cumsum(np.full((1, 4, 3), 0.1), axis=1)
    assert list(moving_tracks(np.concatenate([still, walking]), extent=1.0)) == [False, True]
    with pytest.raises(UserError, match="no reconstruction.npz"):
        ViewerData.load(tmp_path)
    (tmp_path / "reconstruction.npz").write_bytes(b"not a zip")
    with pytest.raises(UserError, match="cannot read"):
        ViewerData.load(tmp_path)


def test_cli_refuses_a_folder_without_outputs_in_one_line(tmp_path, capsys):
    pytest.importorskip("viser")
    assert main(["view", str(tmp_path), "--port", str(free_port())]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no reconstruction.npz" in err[0]
    assert main(["view", str(tmp_path), "--port", "70000"]) == 2
    assert "--port must be in 1..65535" in capsys.readouterr().err


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium on this machine")
def test_chromium_draws_the_points_of_each_frame(output_folder, tmp_path):
    """The page loads with no console errors, and moving the timeline from frame 0 to 23 redraws the scene."""
    pytest.importorskip("viser")
    sync_playwright = pytest.importorskip("playwright.sync_api").sync_playwright
    from d4rt.viz.viser_viewer import serve

    port = free_port()
    server, viewer = serve(output_folder, port=port, block=False)
    errors = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 900, "height": 600})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://127.0.0.1:{port}")
            page.wait_for_selector("canvas", timeout=60_000)

            def settled_screenshot() -> np.ndarray:
                # Redraws arrive over the websocket: wait until two screenshots agree.
                last = None
                for _ in range(40):
                    time.sleep(0.5)
                    shot = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(int)
                    if last is not None and np.array_equal(shot, last):
                        return shot
                    last = shot
                return last

            first = settled_screenshot()
            viewer.frame = 23
            last = settled_screenshot()
            if os.environ.get("D4RT_SCREENSHOT_DIR"):  # the README's screenshot is made here
                Image.fromarray(last.astype(np.uint8)).save(Path(os.environ["D4RT_SCREENSHOT_DIR"]) / "viewer.png",
                                                            optimize=True)
            browser.close()
    finally:
        viewer.close()
        server.stop()
    assert errors == []
    changed = np.abs(first - last).sum(-1) > 30
    scene = changed[:, :560]  # left of the control panel
    assert scene.mean() > 0.01, scene.mean()  # points and frusta moved: drawn per frame
