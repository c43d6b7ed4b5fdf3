"""End to end in a real browser: headless Chromium (Debian's, driven by Playwright; no browser
download) opens the viewer, moves the time slider it finds in the page, and the picture changes to
view_frame's frame at the new time, both as sent by the server and as the browser paints it; the
"Next" button puts the camera at the next named camera; a mouse drag moves the camera, with
reduced-resolution frames while it moves and a full one after.

Skipped when Playwright or a Chromium executable is missing (scripts/setup.sh installs both). Set
M4DGS_VIEWER_SCREENSHOT=PATH to keep a screenshot at the end and M4DGS_VIEWER_RUN=RUN to view that
run instead of the short test run (docs/img/viewer.png is such a screenshot)."""

from __future__ import annotations

import io
import math
import os
import shutil
import time

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")

CHROMIUM = os.environ.get("M4DGS_CHROMIUM") or next(
    (p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None
)
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium executable (apt-get install chromium; scripts/setup.sh)"
)
VIEWPORT = (1000, 600)


def _wait(pred, timeout=90.0, what="condition"):
    end = time.time() + timeout
    while time.time() < end:
        out = pred()
        if out:
            return out
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def _full_frame(viewer, t):
    return next((s for s in viewer.shown.values() if s.full and s.time == t), None)


def _region(img: np.ndarray) -> np.ndarray:
    """The part of the canvas neither the GUI panel (right), the WebGL notice (top left) nor the
    axes gizmo (bottom left) covers."""
    H, W = img.shape[:2]
    return img[int(0.3 * H) : int(0.85 * H), int(0.33 * W) : int(0.62 * W), :3].astype(np.float64)


def _as_painted(img: np.ndarray) -> np.ndarray:
    """A rendered frame stretched over the canvas as the browser paints the background."""
    from PIL import Image

    return np.asarray(Image.fromarray(img).resize(VIEWPORT, Image.BILINEAR))


def _screenshot(page, viewer, path):
    """The page with the cameras, the ground-truth panel and a sharper image, as a PNG of at most
    256 colours (the documentation's picture)."""
    from PIL import Image

    from m4dgs.viewer.cameras import ViewCamera

    page.set_viewport_size({"width": 1280, "height": 860})
    n = len(viewer.log)
    viewer.gui_frusta.value = True
    viewer.gui_res.value = 4.0
    observed = viewer.clip.meta.exposures.observed
    viewer.gui_ev.value = round(math.log2(sorted(observed)[len(observed) // 2]), 1)
    # a step back and up from the first camera, so that its neighbours' frusta show
    cam = viewer.cameras[0].camera
    c2w = cam.c2w.copy()
    c2w[:3, 3] += (-0.5 * c2w[:3, 2] - 0.15 * c2w[:3, 1]) * viewer._scene_scale
    for client in viewer.server.get_clients().values():
        viewer._set_client_camera(client, ViewCamera(cam.K, c2w, cam.width, cam.height))
    if viewer.gui_compare is not None:
        viewer.gui_compare.value = True
    close = page.locator(".mantine-Notification-closeButton")
    if close.count():
        close.first.click()
    time.sleep(1.0)
    _wait(lambda: len(viewer.log) > n and viewer.log[-1][1].full, what="a sharp frame")
    time.sleep(2.0)
    shot = Image.open(io.BytesIO(page.screenshot())).convert("RGB")
    shot.quantize(256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


@pytest.fixture
def browser_model(request):
    """The run M4DGS_VIEWER_RUN names (for a screenshot of a real run), else the short test run."""
    run = os.environ.get("M4DGS_VIEWER_RUN")
    if run:
        from m4dgs.model.trained import load_model

        return load_model(run, device="cpu")
    return request.getfixturevalue("viewer_model")


def test_browser_time_slider_and_camera_drag(browser_model, free_port):
    from PIL import Image

    from m4dgs.viewer.frame import view_frame
    from m4dgs.viewer.server import Viewer

    model = browser_model
    last = model.clip.meta.num_frames - 1
    viewer = Viewer(model, port=free_port, show_cameras=False)
    try:
        with playwright.sync_playwright() as pw:
            browser = pw.chromium.launch(
                executable_path=CHROMIUM,
                headless=True,
                args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"],
            )
            page = browser.new_page(viewport=dict(zip(("width", "height"), VIEWPORT)))
            page.goto(f"http://127.0.0.1:{free_port}/")
            first = _wait(lambda: _full_frame(viewer, 0.0), what="the first full render")
            # the time slider: the one spanning the clip's frames 0 .. G-1
            sliders = page.get_by_role("slider")
            _wait(lambda: sliders.count() >= 1, what="the GUI sliders")
            time_slider = next(
                sliders.nth(i)
                for i in range(sliders.count())
                if sliders.nth(i).get_attribute("aria-valuemin") == "0"
                and sliders.nth(i).get_attribute("aria-valuemax") == str(last)
            )
            time_slider.focus()
            page.keyboard.press("End")
            moved = _wait(lambda: _full_frame(viewer, float(last)), what="a render at the end")
            assert math.isclose(float(viewer.gui_time.value), last)
            # the server sent exactly view_frame's image for the new time, camera and exposure
            ref = view_frame(model, moved.camera, float(last), moved.ev, moved.mode)
            assert np.abs(moved.image.astype(int) - ref.astype(int)).max() <= 1
            before = view_frame(model, moved.camera, 0.0, moved.ev, moved.mode)
            change = np.abs(ref.astype(float) - before.astype(float)).mean()
            assert change > 0.5, f"the scene hardly changes over time ({change:.2f} codes)"

            # and the browser paints it: the screenshot is closer to the new frame than the old
            def painted():
                shot = np.asarray(Image.open(io.BytesIO(page.screenshot())))
                new = np.abs(_region(shot) - _region(_as_painted(moved.image))).mean()
                old = np.abs(_region(shot) - _region(_as_painted(first.image))).mean()
                return (shot, new, old) if new < 0.5 * old and new < 12 else None

            shot, new, old = _wait(painted, timeout=30, what="the browser to paint the frame")
            print(f"painted frame vs new {new:.2f}, vs old {old:.2f} codes (mean abs)")

            # "Next" jumps to the second named camera: its pose, its field of view, its frame
            target = viewer.cameras[1]
            page.get_by_role("button", name="Next").click()

            def at_target():
                s = viewer.log[-1][1] if viewer.log else None
                ok = s is not None and s.full and s.time == target.g
                return s if ok and np.allclose(s.camera.c2w, target.camera.c2w, atol=1e-4) else None

            jumped = _wait(at_target, what=f"a full frame at {target.label}")
            assert viewer.gui_camera.value == target.label
            assert jumped.camera.fov_y == pytest.approx(target.camera.fov_y, rel=1e-4)

            # dragging the camera: reduced-resolution frames while it moves, full when still
            n_before = len(viewer.log)
            page.mouse.move(VIEWPORT[0] * 0.3, VIEWPORT[1] * 0.5)
            page.mouse.down()
            for k in range(12):
                page.mouse.move(VIEWPORT[0] * (0.3 + 0.01 * k), VIEWPORT[1] * 0.5, steps=2)
                time.sleep(0.05)
            page.mouse.up()

            def settled():  # the camera controls glide a little after the mouse is released
                log = list(viewer.log)[n_before:]
                return (
                    log if log and log[-1][1].full and time.time() - viewer.log_time > 1 else None
                )

            after = [s for _, s in _wait(settled, what="a full frame after the drag")]
            low = [s for s in after if not s.full]
            assert low, "no reduced frame while the camera moved"
            full_h, full_w = after[-1].image.shape[:2]
            assert after[-1].full and (full_w, full_h) == viewer.render_size(full_w / full_h)
            assert all(s.image.shape[1] < full_w for s in low)
            assert not np.allclose(after[-1].camera.c2w, jumped.camera.c2w)  # the camera moved

            keep = os.environ.get("M4DGS_VIEWER_SCREENSHOT")
            if keep:
                _screenshot(page, viewer, keep)
            browser.close()
    finally:
        viewer.stop()


def test_browser_clip_viewer_paints_the_frame_unchanged(tiny_clip_oracle, free_port):
    """`m4dgs view CLIP`: the page shows the letterboxed frame with its pixel values (an 8-bit
    frame must not look brighter or darker than it is), and the overlay control changes it."""
    from PIL import Image

    from m4dgs.clip import Clip
    from m4dgs.viewer.clipview import clip_frame, letterbox
    from m4dgs.viewer.server import open_target

    clip = Clip.open(tiny_clip_oracle)
    viewer = open_target(tiny_clip_oracle, port=free_port)
    try:
        with playwright.sync_playwright() as pw:
            browser = pw.chromium.launch(
                executable_path=CHROMIUM,
                headless=True,
                args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"],
            )
            page = browser.new_page(viewport=dict(zip(("width", "height"), VIEWPORT)))
            page.goto(f"http://127.0.0.1:{free_port}/")
            g = clip.train_frames[0]
            for overlay in ("none", "depth"):
                viewer.gui_overlay.value = overlay
                frame = letterbox(clip_frame(clip, g, overlay, truth=True), *VIEWPORT)
                want = _region(_as_painted(frame))

                def painted(want=want):
                    shot = np.asarray(Image.open(io.BytesIO(page.screenshot())))
                    err = np.abs(_region(shot) - want).mean()
                    return err if err < 1.0 else None

                _wait(painted, timeout=60, what=f"the clip frame with overlay {overlay}")
            browser.close()
    finally:
        viewer.stop()
