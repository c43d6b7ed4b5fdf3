"""A trained run as a renderable model: any (time, camera, exposure) -> HDR, LDR, depth, alpha."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
import torch

from m4dgs.clip import Cameras, Clip, frame_time
from m4dgs.core import camera as cam
from m4dgs.core.io import read_json
from m4dgs.core.warp import sample_map
from m4dgs.model.background import Background
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import WorldGaussians
from m4dgs.model.render import render_world
from m4dgs.model.tonemap import ToneMapper
from m4dgs.run import RunDir, load_torch


def _find_clip(run: RunDir) -> Clip:
    info = read_json(run.path("run.json")) if run.path("run.json").exists() else {}
    for key in ("clip", "clip_abs"):
        if key in info:
            p = Path(info[key])
            p = p if p.is_absolute() else (run.root / p)
            if (p / "clip.json").exists():
                return Clip.open(p)
    raise FileNotFoundError(
        f"{run.root}: cannot find the run's clip (run.json 'clip' / 'clip_abs')"
    )


class TrainedModel:
    """Load with `load_model(run_dir)`. Times are fractional training-frame indices (see
    m4dgs.training.data)."""

    def __init__(self, run_dir, clip: Optional[Clip] = None, device="cpu", backend: str = "auto"):
        self.run = RunDir(run_dir)
        self.device = torch.device(device)
        self.backend = backend
        sd = load_torch(self.run.path("model", "final.pt"), map_location=self.device)
        self.clip = clip or _find_clip(self.run)
        self.gauss = WorldGaussians.from_state(sd["gaussians"]).to(self.device)
        cfg = sd["config"]
        self.color = ColorMLP(
            feature_dim=sd.get("feature_dim", 36),
            hidden=cfg["tonemap"]["color_hidden"],
            view_dependent=cfg["tonemap"].get("color_view_dependent", False),
            direction=cfg["tonemap"].get("color_direction", "view"),
            specular=cfg["tonemap"].get("color_specular", False),
        ).to(self.device)
        self.color.load_state_dict(sd["color"])
        self.tm = ToneMapper(
            hidden=cfg["tonemap"]["tonemap_hidden"], lut_size=cfg["tonemap"].get("lut_size", 2048)
        ).to(self.device)
        self.tm.load_state_dict(sd["tonemap"])
        self.bg = Background().to(self.device)
        self.bg.load_state_dict(sd["background"])
        self.K = sd["K"].float().to(self.device)
        self.c2w_train = sd["c2w"].float().to(self.device)
        self.frames = list(sd["frames"])
        self.log2_dt_train = sd["log2_dt"].float()
        self.variant = sd.get("variant")
        cams_path = self.run.path("cameras.json")
        self.cameras = (
            Cameras.from_json(read_json(cams_path), cams_path) if cams_path.exists() else None
        )

    # -- basic facts
    # ----------------------------------------------------------------------------------------------
    @property
    def width(self) -> int:
        return self.clip.width

    @property
    def height(self) -> int:
        return self.clip.height

    @property
    def num_gaussians(self) -> int:
        return self.gauss.num_gaussians

    def time_of(self, g: float) -> float:
        return frame_time(self.clip, g)

    def camera(self, g: int) -> Tuple[np.ndarray, np.ndarray]:
        """Estimated (K [3, 3], c2w [4, 4]) of global frame g (test frames interpolated between
        training frames)."""
        t = self.time_of(g)
        c2w = cam.interpolate_trajectory(
            np.arange(len(self.frames), dtype=np.float64),
            self.c2w_train.detach().cpu().double().numpy(),
            np.array([t]),
        )[0]
        return self.K.detach().cpu().double().numpy(), c2w

    # -- rendering
    # ----------------------------------------------------------------------------------------------
    @torch.no_grad()
    def render(
        self,
        t: float,
        c2w,
        K=None,
        width: Optional[int] = None,
        height: Optional[int] = None,
        log2_dt: Optional[float] = None,
    ) -> Dict[str, Optional[torch.Tensor]]:
        """HDR [H, W, 3], LDR [H, W, 3] (when log2_dt is given), depth [H, W], alpha [H, W] at time
        t."""
        c2w = torch.as_tensor(np.asarray(c2w), dtype=torch.float32, device=self.device)
        K = (
            self.K
            if K is None
            else torch.as_tensor(np.asarray(K), dtype=torch.float32, device=self.device)
        )
        r = render_world(
            self.gauss,
            self.color,
            self.bg,
            float(t),
            c2w,
            K,
            width or self.width,
            height or self.height,
            self.backend,
        )
        ldr = (
            None
            if log2_dt is None
            else self.tm(r.hdr, torch.tensor(float(log2_dt), device=self.device)).clamp(0, 1)
        )
        return {"hdr": r.hdr, "ldr": ldr, "depth": r.depth, "alpha": r.alpha}

    def render_frame(self, g: int, log2_dt: Optional[float] = None):
        K, c2w = self.camera(g)
        return self.render(self.time_of(g), c2w, K, log2_dt=log2_dt)

    @torch.no_grad()
    def tonemap_curve(self, log2_x) -> torch.Tensor:
        """Learned CRF: LDR value per channel [n, 3] at log2 exposure log2(H dt) = log2_x [n]."""
        z = torch.as_tensor(np.asarray(log2_x), dtype=torch.float32, device=self.device)
        return self.tm(
            torch.exp2(z)[:, None].expand(-1, 3).contiguous(), torch.tensor(0.0, device=self.device)
        )

    @torch.no_grad()
    def track_2d(self, uv, g0: int, frames: Sequence[int], min_alpha: float = 0.5) -> torch.Tensor:
        """Induced 2D tracks [N, F, 2]: query pixels uv [N, 2] of frame g0 followed to each frame
        through the Gaussians' motion (alpha-blended destination positions at the query pixels,
        projected in the target camera).

        Queries on which the model has no surface (alpha < min_alpha at g0) or whose point falls
        behind the target camera are NaN."""
        uv = torch.as_tensor(np.asarray(uv), dtype=torch.float32, device=self.device)
        K0, c2w0 = self.camera(g0)
        t0 = self.time_of(g0)
        out = []
        c2w0_t = torch.as_tensor(c2w0, dtype=torch.float32, device=self.device)
        for g in frames:
            K, c2w = self.camera(g)
            r = render_world(
                self.gauss,
                self.color,
                self.bg,
                t0,
                c2w0_t,
                self.K,
                self.width,
                self.height,
                self.backend,
                dest_times=[self.time_of(g)],
            )
            dest = r.dest[0] / r.alpha.clamp_min(1e-6)[..., None]
            p = sample_map(dest, uv)  # [N, 3] world positions at time g
            a = sample_map(r.alpha[..., None], uv)[:, 0]
            w2c = cam.invert_rigid(torch.as_tensor(c2w, dtype=torch.float32, device=self.device))
            pc = cam.transform_points(w2c, p)
            q = cam.project_pinhole(pc, self.K)
            bad = (a < min_alpha) | (pc[:, 2] <= 1e-6)
            out.append(torch.where(bad[:, None], torch.full_like(q, float("nan")), q))
        return torch.stack(out, 1)


def load_model(
    run_dir, device="cpu", clip: Optional[Clip] = None, backend: str = "auto"
) -> TrainedModel:
    return TrainedModel(run_dir, clip=clip, device=device, backend=backend)
