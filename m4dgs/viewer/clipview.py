"""`m4dgs view CLIP`: a clip's frames at their exposures with the priors drawn over them, and the
ground truth beside them when the clip has it.

`clip_frame(clip, g, overlay, truth)` -> uint8 [H, W', 3] is the pure image: the training frame g
as written on the input (its own exposure) with one overlay:

    none     the frame
    depth    the depth prior in false colour (turbo, near = red), half over the frame
    tracks   the prior tracks visible at g as dots (one track in every track_stride, at most one
             per TRACK_AREA pixels), each with its path over the previous TRACK_TAIL training
             frames, one colour per track
    flow     the flow prior from g to the next frame it has flow to, as a colour wheel (hue =
             direction, saturation = magnitude up to the 99th percentile), half over the frame

A test frame (no input) shows its ground truth only. With truth=True and a clip with gt/hdr, the
true LDR image at the frame's exposure (the clip's camera response on gt/hdr) is put on the right.
The server sends it enlarged by a whole factor and letterboxed to each browser window's shape."""

from __future__ import annotations

import colorsys
import math
import threading
import time as _time
from typing import Optional

import numpy as np

from m4dgs.viewer.frame import to_uint8, turbo

OVERLAYS = ("none", "depth", "tracks", "flow")
TRACK_TAIL = 4
TRACK_AREA = 64  # pixels per drawn track (dense prior tracks would cover the frame)
LETTERBOX_GREY = 24


def track_stride(n_tracks: int, clip) -> int:
    """Every how many tracks one is drawn: at most one per TRACK_AREA pixels of the frame."""
    return max(1, math.ceil(n_tracks / max(16, clip.width * clip.height // TRACK_AREA)))


def track_colour(n: int):
    """RGB floats of track n (golden-ratio hues)."""
    return colorsys.hsv_to_rgb((n * 0.618033988749895) % 1.0, 0.85, 1.0)


def flow_colours(flow: np.ndarray) -> np.ndarray:
    """[H, W, 3] floats in [0, 1] of a flow field [H, W, 2]: hue = direction, saturation =
    magnitude / its 99th percentile, value 1."""
    import matplotlib.colors as mcolors

    mag = np.linalg.norm(flow, axis=-1)
    ang = np.arctan2(flow[..., 1], flow[..., 0])
    top = max(float(np.percentile(mag, 99)), 1e-6)
    hsv = np.stack([(ang + np.pi) / (2 * np.pi), np.clip(mag / top, 0, 1), np.ones_like(mag)], -1)
    return mcolors.hsv_to_rgb(hsv)


def _dot(img: np.ndarray, x: float, y: float, rgb, r: int = 1) -> None:
    H, W = img.shape[:2]
    xi, yi = int(np.floor(x)), int(np.floor(y))
    img[max(0, yi - r) : min(H, yi + r + 1), max(0, xi - r) : min(W, xi + r + 1)] = rgb


def _truth_at(clip, g: int) -> Optional[np.ndarray]:
    from m4dgs.core.crf import tonemap_ldr

    if not clip.has_gt or clip.meta.crf is None or not clip.has_gt_part("hdr"):
        return None
    dt = clip.meta.train_dt_of(g) if g in clip.train_frames else _test_dt(clip, g)
    return tonemap_ldr(clip.load_gt_hdr(g), dt, clip.meta.crf)


def _test_dt(clip, g: int) -> float:
    ex = clip.meta.exposures
    if ex.test_dt is not None:
        return float(ex.test_dt[clip.test_frames.index(g)])
    return float(ex.observed[0])


def clip_frame(clip, g: int, overlay: str = "none", truth: bool = True) -> np.ndarray:
    """The clip viewer's image of global frame g (module docstring); uint8 [H, W, 3], or
    [H, 2 W + 2, 3] with the truth beside it."""
    if overlay not in OVERLAYS:
        raise ValueError(f"unknown overlay {overlay!r}; known: {', '.join(OVERLAYS)}")
    if g not in clip.meta.frames:
        raise ValueError(f"{clip.root}: no frame {g} (frames 0..{clip.meta.num_frames - 1})")
    gt = _truth_at(clip, g) if truth or g not in clip.train_frames else None
    if g not in clip.train_frames:
        if gt is None:
            return np.zeros((clip.height, clip.width, 3), np.uint8)
        return gt
    img = clip.load_ldr(g).astype(np.float64) / 255.0
    if overlay == "depth":
        d = clip.load_depth_prior(g).astype(np.float64)
        ok = d > 0
        inv = np.where(ok, 1.0 / np.maximum(d, 1e-12), 0.0)
        lo, hi = np.percentile(inv[ok], [2.0, 98.0]) if ok.any() else (0.0, 1.0)
        col = turbo((inv - lo) / max(hi - lo, 1e-12)) * ok[..., None]
        img = 0.5 * img + 0.5 * col
    elif overlay == "flow" and clip.has_flow_prior():
        fs = clip.load_flow_prior()
        pairs = [int(b) for a, b in fs.pairs if int(a) == g]
        if pairs:
            b = min(pairs, key=lambda x: (x < g, abs(x - g)))
            flow, valid = fs.get(g, b)
            img = 0.5 * img + 0.5 * flow_colours(flow) * valid[..., None]
    elif overlay == "tracks":
        ts = clip.load_tracks_prior()
        i = clip.train_frames.index(g)
        r = 1 if min(clip.width, clip.height) >= 200 else 0
        for n in range(0, ts.tracks.shape[0], track_stride(ts.tracks.shape[0], clip)):
            if not ts.visible[n, i]:
                continue
            rgb = track_colour(n)
            for j in range(max(0, i - TRACK_TAIL), i):
                if ts.visible[n, j]:
                    _dot(img, *ts.tracks[n, j], rgb, r=0)
            _dot(img, *ts.tracks[n, i], rgb, r=r)
    out = to_uint8(img)
    if gt is not None and truth:
        gap = np.full((out.shape[0], 2, 3), 255, np.uint8)
        out = np.concatenate([out, gap, gt], axis=1)
    return out


def letterbox(img: np.ndarray, width: int, height: int, max_side: int = 2048) -> np.ndarray:
    """uint8 img [h, w, 3] enlarged by a whole factor (nearest; at most fitting width x height and
    max_side) and centred on a dark grey canvas of the aspect width / height, so that a browser
    stretching it over a width x height canvas shows it undistorted."""
    h, w = img.shape[:2]
    k = max(1, min(width // w, height // h, max_side // max(h, w)))
    big = np.repeat(np.repeat(img, k, axis=0), k, axis=1)
    H, W = big.shape[:2]
    aspect = width / max(height, 1)
    cw, ch = (max(W, round(H * aspect)), H) if W / H < aspect else (W, max(H, round(W / aspect)))
    out = np.full((ch, cw, 3), LETTERBOX_GREY, np.uint8)
    y0, x0 = (ch - H) // 2, (cw - W) // 2
    out[y0 : y0 + H, x0 : x0 + W] = big
    return out


class ClipViewer:
    """A viser server showing `clip_frame` letterboxed in each browser's window (the scene's
    background image, so its pixels are shown as they are), with a frame slider (play/pause,
    FPS), the overlay and the truth toggle. Same host/port rules as m4dgs.viewer.server.Viewer."""

    def __init__(self, clip, host: str = "127.0.0.1", port: int = 8080, verbose: bool = False):
        from m4dgs.viewer.web import import_viser

        viser = import_viser()
        self.clip = clip
        self._stop = threading.Event()
        self.server = viser.ViserServer(
            host=host, port=port, label="m4dgs view (clip)", verbose=verbose
        )
        # looking along +z from the origin, as a run's first camera does: the background image
        # alone fills the window, its pixels unchanged
        ic = self.server.initial_camera
        ic.position, ic.look_at, ic.up = (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)
        gui = self.server.gui
        G = clip.meta.num_frames
        self.gui_frame = gui.add_slider("Frame", min=0, max=G - 1, step=1, initial_value=0)
        self.gui_play = gui.add_button("Play")
        self.gui_fps = gui.add_number("FPS", initial_value=float(clip.meta.fps), min=0.5, max=60.0)
        self.gui_overlay = gui.add_dropdown("Overlay", options=OVERLAYS, initial_value="none")
        self.gui_truth = gui.add_checkbox("Ground truth beside", initial_value=clip.has_gt)
        self.gui_info = gui.add_markdown("")
        self._playing = False
        self._image = None
        self._version = 0
        self._lock = threading.Lock()
        self.gui_play.on_click(lambda _: self._toggle())
        for h in (self.gui_frame, self.gui_overlay, self.gui_truth):
            h.on_update(lambda _: self.update())
        self.update()
        self.server.on_client_connect(self._on_connect)
        threading.Thread(target=self._play_loop, daemon=True).start()

    @property
    def port(self) -> int:
        return self.server.get_port()

    def _toggle(self) -> None:
        self._playing = not self._playing
        self.gui_play.label = "Pause" if self._playing else "Play"

    def _play_loop(self) -> None:
        while not self._stop.is_set():
            _time.sleep(1.0 / max(float(self.gui_fps.value or 1.0), 0.5))
            if self._playing:
                g = int(self.gui_frame.value) + 1
                self.gui_frame.value = 0 if g >= self.clip.meta.num_frames else g

    def update(self) -> None:
        """Compose the image of the current controls (every browser picks it up)."""
        g = int(self.gui_frame.value)
        img = clip_frame(self.clip, g, self.gui_overlay.value, bool(self.gui_truth.value))
        with self._lock:
            self._image, self._version = img, self._version + 1
        m = self.clip.meta
        kind = f"training frame, dt {m.train_dt_of(g):g}" if g in m.split.train else "test frame"
        self.gui_info.content = f"Frame {g:05d}: {kind}"

    def _on_connect(self, client) -> None:
        threading.Thread(target=self._client_loop, args=(client,), daemon=True).start()

    def _client_loop(self, client) -> None:
        last = None
        while not self._stop.is_set():
            _time.sleep(0.05)
            cam = client.camera
            try:
                if cam.update_timestamp == 0.0 or cam.image_height <= 0:
                    continue
                size = (int(cam.image_width), int(cam.image_height))
            except AssertionError:
                continue
            with self._lock:
                img, version = self._image, self._version
            if (version, size) == last:
                continue
            try:
                client.scene.set_background_image(letterbox(img, *size), format="png")
            except Exception:  # the browser left
                return
            last = (version, size)

    def serve(self) -> None:
        try:
            while not self._stop.is_set():
                _time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        self._stop.set()
        self.server.stop()
