"""The viewer's web server (viser): a free-flying browser camera over a trained run, rendered on the
server and shown as the scene's background image, with GUI controls for time, exposure, display
mode, named cameras and the ground-truth comparison, and the training cameras drawn in 3D.

One render thread per connected browser polls its state every POLL_S seconds and renders when the
camera or a control changed: at MOVING_SCALE of the resolution (JPEG) while the camera moves, then
once more at full resolution (PNG) when it has been still for STILL_S seconds. The server listens
only where `host` says (127.0.0.1 by default) and serves viser's own client page, nothing else."""

from __future__ import annotations

import math
import threading
import time as _time
from collections import deque
from dataclasses import dataclass
from typing import Deque, Dict, List, Optional, Tuple

import numpy as np

from m4dgs.viewer import truth
from m4dgs.viewer.cameras import NamedCamera, ViewCamera, from_browser, named_cameras, to_browser
from m4dgs.viewer.frame import MODES, view_frame
from m4dgs.viewer.web import import_viser

POLL_S = 0.03
STILL_S = 0.25
MOVING_SCALE = 0.5
LOG_LEN = 64
TRUTH_PANEL_WIDTH = 600  # the comparison image is enlarged to at least this many pixels wide


@dataclass
class Shown:
    """What a browser was last sent: the image and everything it was rendered from."""

    image: np.ndarray
    camera: ViewCamera
    time: float
    ev: float
    mode: str
    full: bool


class Viewer:
    """A viser server over `model` (m4dgs.model.trained.TrainedModel). Construct, then `serve()`
    blocks; or use it from another thread and `stop()` it. show_cameras: the initial state of the
    "Cameras (3D)" switch (the frusta of the named cameras and the training path)."""

    def __init__(
        self,
        model,
        host: str = "127.0.0.1",
        port: int = 8080,
        show_cameras: bool = True,
        verbose: bool = False,
    ):
        viser = import_viser()

        self.model = model
        self.clip = model.clip
        self.cameras: List[NamedCamera] = named_cameras(model)
        self.by_label: Dict[str, NamedCamera] = {c.label: c for c in self.cameras}
        self.shown: Dict[int, Shown] = {}
        # every image sent, oldest first (the last LOG_LEN): (client id, Shown)
        self.log: Deque[Tuple[int, Shown]] = deque(maxlen=LOG_LEN)
        self.log_time = 0.0  # when the last image was sent
        self._moved: Dict[int, float] = {}
        self._lock = threading.Lock()
        self._render_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: List[threading.Thread] = []
        self.selected: NamedCamera = self.cameras[0]

        self.server = viser.ViserServer(host=host, port=port, label="m4dgs view", verbose=verbose)
        self._scene_scale = self._estimate_scene_scale()
        self._init_camera(self.selected.camera)
        self._camera_handles: list = []
        self._build_gui(show_cameras)
        self._draw_cameras()
        self._show_cameras()
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        self._player = threading.Thread(target=self._play_loop, daemon=True, name="viewer-play")
        self._player.start()

    # -- facts
    # ----------------------------------------------------------------------------------------------
    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def host(self) -> str:
        return self.server.get_host()

    def _estimate_scene_scale(self) -> float:
        """Median distance from the first training camera to the Gaussians (frustum sizes)."""
        pos = self.model.gauss.positions(0.0).detach().cpu().double().numpy()
        c0 = self.selected.camera.c2w[:3, 3]
        d = float(np.median(np.linalg.norm(pos - c0, axis=1))) if len(pos) else 1.0
        return d if math.isfinite(d) and d > 0 else 1.0

    # -- GUI
    # ----------------------------------------------------------------------------------------------
    def _build_gui(self, show_cameras: bool) -> None:
        gui = self.server.gui
        clip = self.clip
        G = clip.meta.num_frames
        levels = np.log2(np.asarray(clip.meta.exposures.observed + clip.meta.exposures.novel))
        ev0 = float(np.log2(clip.train_dt[0]))
        with gui.add_folder("Time"):
            self.gui_time = gui.add_slider(
                "Frame", min=0.0, max=float(G - 1), step=0.1, initial_value=0.0
            )
            self.gui_play = gui.add_button("Play")
            self.gui_fps = gui.add_number(
                "FPS", initial_value=float(clip.meta.fps), min=0.5, max=60.0, step=0.5
            )
        with gui.add_folder("Exposure"):
            self.gui_ev = gui.add_slider(
                "EV (log2 dt)",
                min=math.floor(float(levels.min())) - 4.0,
                max=math.ceil(float(levels.max())) + 4.0,
                step=0.1,
                initial_value=round(ev0, 1),
                hint="Exposure as log2 of the exposure time; the LDR mode applies the run's "
                "learned tone mapper at it",
            )
        with gui.add_folder("Display"):
            self.gui_mode = gui.add_dropdown("Mode", options=MODES, initial_value="ldr")
            self.gui_res = gui.add_slider(
                "Resolution",
                min=0.25,
                max=4.0,
                step=0.25,
                initial_value=1.0,
                hint="Image width as a multiple of the clip's width",
            )
            self.gui_centres = gui.add_checkbox("Gaussian centres (3D)", initial_value=False)
            self.gui_frusta = gui.add_checkbox("Cameras (3D)", initial_value=show_cameras)
        with gui.add_folder("Cameras"):
            self.gui_camera = gui.add_dropdown(
                "Camera", options=[c.label for c in self.cameras], initial_value=self.selected.label
            )
            self.gui_prev = gui.add_button("Previous")
            self.gui_next = gui.add_button("Next")
        self.gui_compare = None
        if any(truth.has_truth(clip, c) for c in self.cameras):
            with gui.add_folder("Ground truth"):
                self.gui_compare = gui.add_checkbox("Compare at camera", initial_value=False)
                self.gui_truth_text = gui.add_markdown("")
                self.gui_truth_img = gui.add_image(
                    np.zeros((8, 26, 3), np.uint8), label="render | truth | error", format="png"
                )

        self.gui_play.on_click(lambda _: self._toggle_play())
        self.gui_camera.on_update(lambda e: self._jump(self.by_label[self.gui_camera.value], e))
        self.gui_prev.on_click(lambda e: self._step_camera(-1, e))
        self.gui_next.on_click(lambda e: self._step_camera(1, e))
        self.gui_centres.on_update(lambda _: self._update_centres())
        self.gui_frusta.on_update(lambda _: self._show_cameras())
        self.gui_time.on_update(lambda _: self._update_centres())
        self.gui_ev.on_update(lambda _: self._after_exposure())
        if self.gui_compare is not None:
            self.gui_compare.on_update(lambda _: self._update_truth())
        self._playing = False

    def _toggle_play(self) -> None:
        self._playing = not self._playing
        self.gui_play.label = "Pause" if self._playing else "Play"

    def _play_loop(self) -> None:
        last = _time.monotonic()
        while not self._stop.is_set():
            _time.sleep(0.01)
            now = _time.monotonic()
            fps = float(self.gui_fps.value or 1.0)
            if not self._playing:
                last = now
                continue
            if now - last >= 1.0 / max(fps, 0.5):
                last = now
                G = self.clip.meta.num_frames
                t = math.floor(float(self.gui_time.value) + 1e-6) + 1.0
                self.gui_time.value = 0.0 if t > G - 1 else t

    def _step_camera(self, d: int, event) -> None:
        i = [c.label for c in self.cameras].index(self.selected.label)
        self.gui_camera.value = self.cameras[(i + d) % len(self.cameras)].label

    def _after_exposure(self) -> None:
        self._update_centres()
        self._update_truth()

    # -- cameras
    # ----------------------------------------------------------------------------------------------
    def _init_camera(self, camera: ViewCamera) -> None:
        ic = self.server.initial_camera
        c2w = camera.c2w
        ic.position = tuple(c2w[:3, 3])
        ic.look_at = tuple(c2w[:3, 3] + c2w[:3, 2] * self._scene_scale)
        ic.up = tuple(-c2w[:3, 1])
        ic.fov = camera.fov_y

    def _set_client_camera(self, client, camera: ViewCamera) -> None:
        wxyz, pos, fov = to_browser(camera)
        with client.atomic():
            client.camera.up_direction = -camera.c2w[:3, 1]
            client.camera.position = pos
            client.camera.wxyz = wxyz
            client.camera.fov = fov

    def _jump(self, named: NamedCamera, event=None) -> None:
        """Put every browser at `named` and the time slider at its frame."""
        self.selected = named
        if self.gui_camera.value != named.label:
            self.gui_camera.value = named.label
        self.gui_time.value = float(named.g)
        for client in self.server.get_clients().values():
            self._set_client_camera(client, named.camera)
        self._update_truth()

    def _draw_cameras(self) -> None:
        s = 0.08 * self._scene_scale
        colours = {"train": (40, 120, 255), "test": (255, 150, 30), "view": (220, 40, 200)}
        for named in self.cameras:
            wxyz, pos, fov = to_browser(named.camera)
            h = self.server.scene.add_camera_frustum(
                f"/cameras/{named.kind}/{named.label.replace(' ', '_')}",
                fov=fov,
                aspect=named.camera.width / named.camera.height,
                scale=s,
                wxyz=wxyz,
                position=pos,
                color=colours[named.kind],
                thickness=1.5,
                thickness_units="screen",
            )
            h.on_click(lambda e, n=named: self._jump(n, e))
            self._camera_handles.append(h)
        path = np.array([c.camera.c2w[:3, 3] for c in self.cameras if c.kind == "train"])
        if len(path) >= 2:
            seg = np.stack([path[:-1], path[1:]], axis=1)
            self._camera_handles.append(
                self.server.scene.add_line_segments(
                    "/cameras/path",
                    points=seg,
                    colors=(40, 120, 255),
                    thickness=2.0,
                    thickness_units="screen",
                )
            )

    def _show_cameras(self) -> None:
        for h in self._camera_handles:
            h.visible = bool(self.gui_frusta.value)

    # -- 3D point cloud and truth
    # ----------------------------------------------------------------------------------------------
    def _update_centres(self) -> None:
        if not self.gui_centres.value:
            self._centres_handle_remove()
            return
        import torch

        from m4dgs.model.color import color_directions
        from m4dgs.model.render import gaussian_colors

        m = self.model
        with torch.no_grad():
            t = m.time_of(float(self.gui_time.value))
            pos = m.gauss.positions(t)
            # a view-dependent colour is the one seen from the selected camera
            c = torch.as_tensor(self.selected.camera.c2w[:3, 3], dtype=pos.dtype).to(pos.device)
            dirs = color_directions(m.color, pos, m.gauss.quats(t), m.gauss.scales(), c)
            hdr = gaussian_colors(m.gauss, m.color, t, dirs)
            rgb = m.tm(hdr, torch.tensor(float(self.gui_ev.value), dtype=hdr.dtype))
        cols = np.clip(np.round(rgb.clamp(0, 1).cpu().numpy() * 255), 0, 255).astype(np.uint8)
        self._centres = self.server.scene.add_point_cloud(
            "/centres",
            points=pos.cpu().numpy().astype(np.float32),
            colors=cols,
            point_size=0.004 * self._scene_scale,
        )

    def _centres_handle_remove(self) -> None:
        h = getattr(self, "_centres", None)
        if h is not None:
            h.remove()
            self._centres = None

    def truth_image(self) -> Optional[Tuple[np.ndarray, float]]:
        """(render | truth | error image, mean absolute error in codes) at the selected camera,
        its frame and the exposure slider; None where the clip has no truth there."""
        named, ev = self.selected, float(self.gui_ev.value)
        gt = truth.truth_ldr(self.clip, named, ev)
        if gt is None:
            return None
        with self._render_lock:
            r = view_frame(self.model, named.camera, float(named.g), ev, "ldr")
        return truth.comparison(r, gt), truth.mean_abs_error(r, gt)

    def _update_truth(self) -> None:
        if self.gui_compare is None or not self.gui_compare.value:
            return
        out = self.truth_image()
        if out is None:
            self.gui_truth_text.content = f"No ground truth at {self.selected.label}."
            return
        img, err = out
        k = max(1, math.ceil(TRUTH_PANEL_WIDTH / img.shape[1]))  # small clips: whole pixels, larger
        self.gui_truth_img.image = np.repeat(np.repeat(img, k, axis=0), k, axis=1)
        self.gui_truth_text.content = (
            f"{self.selected.label}, EV {float(self.gui_ev.value):.1f}: mean |error| "
            f"{err:.2f} codes (error map 0 .. {truth.ERROR_RANGE:g})"
        )

    # -- per-browser rendering
    # ----------------------------------------------------------------------------------------------
    def _on_connect(self, client) -> None:
        self._moved[client.client_id] = 0.0
        client.camera.on_update(lambda c: self._moved.__setitem__(client.client_id, _time.time()))
        th = threading.Thread(
            target=self._render_loop, args=(client,), daemon=True, name=f"viewer-{client.client_id}"
        )
        self._threads.append(th)
        th.start()

    def _on_disconnect(self, client) -> None:
        self._moved.pop(client.client_id, None)

    def render_size(self, aspect: float) -> Tuple[int, int]:
        """Full-resolution image size for a browser canvas of this aspect (width / height)."""
        w = max(8, round(self.clip.width * float(self.gui_res.value)))
        return w, max(8, round(w / max(aspect, 1e-3)))

    def _render_loop(self, client) -> None:
        cid = client.client_id
        last_key, last_full = None, False
        while not self._stop.is_set() and cid in self._moved:
            _time.sleep(POLL_S)
            cam = client.camera
            try:
                if cam.update_timestamp == 0.0 or cam.image_height <= 0:
                    continue
                wxyz, pos, fov, aspect = (
                    np.array(cam.wxyz),
                    np.array(cam.position),
                    float(cam.fov),
                    cam.aspect,
                )
            except (AssertionError, ZeroDivisionError):
                continue
            t, ev, mode = float(self.gui_time.value), float(self.gui_ev.value), self.gui_mode.value
            key = (
                tuple(np.round(wxyz, 6)),
                tuple(np.round(pos, 6)),
                round(fov, 6),
                round(aspect, 4),
                t,
                ev,
                mode,
                float(self.gui_res.value),
            )
            moving = _time.time() - self._moved.get(cid, 0.0) < STILL_S
            if key == last_key and (last_full or moving):
                continue
            w, h = self.render_size(aspect)
            camera = from_browser(wxyz, pos, fov, w, h)
            if moving:
                camera = camera.scaled(MOVING_SCALE)
            try:
                with self._render_lock:
                    img = view_frame(self.model, camera, t, ev, mode)
                client.scene.set_background_image(
                    img, format="jpeg" if moving else "png", jpeg_quality=85
                )
            except Exception as e:  # a browser that left mid-render, a failed render
                if cid not in self._moved:
                    return
                print(f"[m4dgs view] render failed: {type(e).__name__}: {e}", flush=True)
                _time.sleep(1.0)
                continue
            self.shown[cid] = Shown(img, camera, t, ev, mode, not moving)
            self.log.append((cid, self.shown[cid]))
            self.log_time = _time.time()
            last_key, last_full = key, not moving

    # -- life cycle
    # ----------------------------------------------------------------------------------------------
    def serve(self) -> None:
        """Block until interrupted (Ctrl-C), then stop."""
        try:
            while not self._stop.is_set():
                _time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        self._stop.set()
        for th in self._threads:  # let a render in flight finish before the connections close
            th.join(timeout=5.0)
        self.server.stop()


def open_target(target, host: str = "127.0.0.1", port: int = 8080, device: str = "auto"):
    """A running viewer of a run folder (model/final.pt) or a clip folder (clip.json); raises
    InputError naming the folder when it is neither, or a run that has not finished training."""
    from pathlib import Path

    from m4dgs.core.errors import InputError

    target = Path(target)
    if (target / "clip.json").is_file():
        from m4dgs.clip import Clip
        from m4dgs.viewer.clipview import ClipViewer

        return ClipViewer(Clip.open(target), host=host, port=port)
    if not (target / "model" / "final.pt").is_file():
        what = (
            "a run that has not finished training"
            if (target / "run.json").is_file()
            else "neither a run folder nor a clip folder"
        )
        raise InputError(
            f"{target / 'model' / 'final.pt'}: missing: {target} is {what} (m4dgs view takes a "
            "trained run folder, with model/final.pt, or a clip folder, with clip.json)"
        )
    from m4dgs.core.device import resolve_device
    from m4dgs.model.trained import load_model

    model = load_model(target, device=str(resolve_device(device)))
    return Viewer(model, host=host, port=port)
