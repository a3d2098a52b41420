"""`d4rt app`: the gradio web app end to end through its own HTTP API (gradio's client) and in headless
Chromium. The server binds to 127.0.0.1 on a free port and is closed by the fixture."""

from __future__ import annotations

import io
import os
import re
import shutil
import socket
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

gr = pytest.importorskip("gradio")
from gradio_client import Client, handle_file  # noqa: E402

from d4rt.cli.app import RESOLUTIONS, build_app  # noqa: E402

FAST = next(iter(RESOLUTIONS))  # the encoder's resolution
PROMISED = {"reconstruction.npz", "depth.mp4", "points.ply", "scene.glb", "trajectory_tum.txt", "tracks.mp4",
            "viewer.html", "trajectory.png", "colmap/sparse/0/points3D.bin"}
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                 "--no-sandbox"]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = build_app(work_dir=str(tmp_path_factory.mktemp("app-work")))
    app.launch(server_name="127.0.0.1", server_port=port, prevent_thread_lock=True, quiet=True, max_file_size="5mb")
    try:
        yield app, f"http://127.0.0.1:{port}"
    finally:
        app.close()


def zip_names(path: str) -> set[str]:
    with zipfile.ZipFile(path) as z:
        return set(z.namelist())


@pytest.mark.slow(seconds=41)
def test_sample_in_every_promised_file_out_and_requests_apart(served, tmp_path):
    app, url = served
    before = set(Path(app.work_root).iterdir())
    client = Client(url, verbose=False)
    glb, depth_video, tracks_video, trajectory, archive, summary = client.predict(
        None, True, 6, 1, FAST, "", api_name="/reconstruct")
    assert "6 frames of 640x480 reconstructed" in summary
    assert all(Path(p).stat().st_size > 0 for p in (glb, depth_video, tracks_video, trajectory, archive))
    first = zip_names(archive)
    assert PROMISED <= first, PROMISED - first
    # A second request (an uploaded array of 4 frames) gets a folder of its own: nothing of the first in it.
    frames = (np.random.default_rng(0).random((4, 48, 64, 3)) * 255).astype(np.uint8)
    np.save(tmp_path / "clip.npy", frames)
    *_, archive2, summary2 = client.predict(handle_file(str(tmp_path / "clip.npy")), False, 6, 1, FAST, "",
                                            api_name="/reconstruct")
    assert "4 frames of 64x48 reconstructed" in summary2
    with zipfile.ZipFile(archive2) as z, np.load(io.BytesIO(z.read("reconstruction.npz"))) as npz:
        assert npz["depth"].shape[0] == 4
    folders = sorted(set(Path(app.work_root).iterdir()) - before)
    assert len(folders) == 2 and all((f / "d4rt-output.zip").is_file() for f in folders)
    with zipfile.ZipFile(folders[0] / "d4rt-output.zip") as z, np.load(io.BytesIO(z.read("reconstruction.npz"))) as a:
        with zipfile.ZipFile(folders[1] / "d4rt-output.zip") as y, np.load(io.BytesIO(y.read("reconstruction.npz"))) as b:
            assert {a["depth"].shape[0], b["depth"].shape[0]} == {6, 4}


def test_a_corrupt_upload_gets_the_clis_one_line_error(served, tmp_path):
    _, url = served
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video" * 50)
    with pytest.raises(Exception) as caught:
        Client(url, verbose=False).predict(handle_file(str(bad)), False, 6, 1, FAST, "", api_name="/reconstruct")
    message = str(caught.value).strip()
    assert "cannot decode video bad.mp4" in message and "\n" not in message and "request-" not in message
    with pytest.raises(Exception, match="upload a video or a zip of images"):
        Client(url, verbose=False).predict(None, False, 6, 1, FAST, "", api_name="/reconstruct")
    big = tmp_path / "big.npy"  # over the 5 MB this app was started with
    np.save(big, np.zeros((20, 100, 1000, 3), np.uint8))
    with pytest.raises(Exception, match="exceeds the maximum file size"):
        Client(url, verbose=False).predict(handle_file(str(big)), False, 6, 1, FAST, "", api_name="/reconstruct")


@pytest.mark.slow(seconds=98)
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium on this machine")
def test_the_result_page_shows_the_3d_view(served):
    sync_playwright = pytest.importorskip("playwright.sync_api").sync_playwright
    _, url = served
    errors = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 1100})
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        page.get_by_label(re.compile("bundled sample")).check()
        page.get_by_role("button", name="Reconstruct").click()
        page.get_by_text(re.compile("frames of 640x480 reconstructed")).wait_for(timeout=300_000)
        canvas = page.locator("canvas").first
        canvas.wait_for(timeout=60_000)
        time.sleep(3)  # the GLB loads into the 3D view
        view = np.asarray(Image.open(io.BytesIO(canvas.screenshot())).convert("RGB")).astype(float)
        if os.environ.get("D4RT_SCREENSHOT_DIR"):  # the README's screenshot is made here (small: 800 px wide)
            shot = Image.open(io.BytesIO(page.screenshot(full_page=True))).convert("RGB")
            shot.resize((800, round(shot.height * 800 / shot.width)), Image.LANCZOS).quantize(256).save(
                Path(os.environ["D4RT_SCREENSHOT_DIR"]) / "app.png", optimize=True)
        browser.close()
    assert errors == []
    assert view.shape[0] > 200 and view.std(axis=(0, 1)).max() > 10  # points drawn, not an empty canvas


def test_only_the_newest_request_folders_stay(tmp_path):
    from d4rt.cli.app import prune_requests

    for i in range(5):
        folder = tmp_path / f"request-{i}"
        folder.mkdir()
        (folder / "d4rt-output.zip").write_bytes(b"x")
        os.utime(folder, (1000 + i, 1000 + i))
    (tmp_path / "other").mkdir()
    prune_requests(tmp_path, keep=2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other", "request-3", "request-4"]
