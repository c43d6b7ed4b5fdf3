"""Stage 1: video HDR Gaussians in orthographic camera space (paper sec. 3.3.1, 3.3.3; appendix).

Fully dynamic Gaussians live in video space (x, y in [-1, 1] normalised image coordinates, z = prior
depth) and are rendered with the orthographic camera J_ortho = [[W/2, 0, 0], [0, H/2, 0]], so camera
and object motion are both Gaussian motion and no camera is needed. Each iteration samples a
training time t and renders, in ONE pass, the HDR image, depth, alpha and the Gaussians' positions
at destination times (extra feature channels) from which the rendered flow / track maps follow.
Losses (m4dgs.training.objective, weights in `config.Stage1Config.loss`): LDR RGB (0.8 L1 + 0.2
D-SSIM) through the learned tone mapper, unit exposure, depth L1, flow (t' = t +- N_e) or track
(random t') loss, ARAP, velocity and acceleration smoothness, and temporal luminance regularisation
after densification. Only training LDR frames, their exposure times and the priors are used, never
ground truth."""

from __future__ import annotations

from typing import Any, Callable, Dict, List, Optional, Sequence

import torch

from m4dgs.core import camera as cam
from m4dgs.core.crf import get_crf, log_logistic, reinhard_anchored
from m4dgs.model.background import Background
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import VideoGaussians, init_video_gaussians
from m4dgs.model.render import RenderResult, render_gaussians
from m4dgs.model.tonemap import ToneMapper, pretrain_tonemapper
from m4dgs.training.config import TrainConfig
from m4dgs.training.data import TrainingData, init_tracks, stage1_data
from m4dgs.training.densify import Strategy
from m4dgs.training.objective import CameraModel, Trajectories
from m4dgs.training.stage import (
    SPLINE_KEYS,
    GaussianSet,
    Stage,
    check_gain,
    gaussian_keys,
    gaussian_optimizers,
    module_optimizers,
    train_loop,
)

# the optimised attributes of the video Gaussians (and "log2_gain" with a gain over time, beyond
# the paper: `gaussian_keys`)
GAUSSIAN_KEYS = SPLINE_KEYS


def build_appearance(cfg: TrainConfig, c0: float, device, pretrain: bool = True) -> tuple:
    """Colour MLP (36 + 3 -> 36 -> 3, 2^x output; the view direction only when
    tonemap.color_view_dependent, mirrored about the normals with tonemap.color_direction =
    "reflected") and the per-channel tone mapper, pre-trained on a generic curve."""
    color = ColorMLP(
        feature_dim=cfg.model.feature_dim,
        hidden=cfg.tonemap.color_hidden,
        view_dependent=cfg.tonemap.color_view_dependent,
        direction=cfg.tonemap.color_direction,
        specular=cfg.tonemap.color_specular,
    ).to(device)
    tm = ToneMapper(hidden=cfg.tonemap.tonemap_hidden, lut_size=cfg.tonemap.lut_size).to(device)
    if pretrain and cfg.tonemap.pretrain_steps > 0:
        pretrain_tonemapper(
            tm,
            pretrain_curve(cfg.tonemap.pretrain_crf, c0),
            iters=cfg.tonemap.pretrain_steps,
            mono_weight=cfg.tonemap.pretrain_monotonic_weight,
            c0=c0,
        )
    bg = Background(cfg.tonemap.learn_background).to(device)
    return color, tm, bg


def pretrain_curve(name: str, c0: float) -> Callable:
    """Tone-mapper pre-training target f(x) on linear exposure x (see ToneMapConfig.pretrain_crf).

    "log-logistic": m4dgs.core.crf.log_logistic(c0) (default; generic, anchored only at f(1) = c0);
    "reinhard-c0" or "auto": m4dgs.core.crf.reinhard_anchored(c0) (the former default: the HDR-NeRF
    curve when c0 = 0.73); otherwise a registered m4dgs.core.crf name (the reference channel of a
    per-channel curve)."""
    if name == "log-logistic":
        crf = log_logistic(c0)
        return lambda x: crf(x)
    if name in ("reinhard-c0", "auto"):
        crf = reinhard_anchored(c0)
        return lambda x: crf(x)
    crf = get_crf(name)
    return lambda x: crf(x)


class VideoStage(Stage):
    """Stage-1 model + optimisation state. `step(it)` runs one iteration
    (m4dgs.training.stage.Stage); `state_dict()` / `load_state_dict()` resume."""

    section = "stage1"
    # Stage 1 has always rendered the target's destination map, used or not (flow / track loss off:
    # the no-track-loss ablation). Those extra feature channels change the rasterizer's sums in the
    # last bits, so dropping them would change that ablation's results; kept for reproducibility.
    always_render_target = True

    def __init__(
        self,
        data: TrainingData,
        cfg: TrainConfig,
        device="cpu",
        backend: str = "auto",
        init: bool = True,
    ):
        data, chain = stage1_data(data, cfg.stage1.init)
        super().__init__(data, cfg, device, backend, seed=cfg.seed)
        self.K = torch.tensor(cam.K_ortho(self.W, self.H), dtype=torch.float32, device=self.device)
        self.viewmat = torch.eye(4, dtype=torch.float32, device=self.device)
        self.camera = CameraModel()  # the orthographic video camera: no poses, prior-depth units
        self.gauss: Optional[VideoGaussians] = None
        if init:
            tracks, vis, always = init_tracks(data, cfg.stage1.init, chain)
            g = init_video_gaussians(
                tracks.to(self.device),
                vis.to(self.device),
                data.depth.to(self.device),
                self.W,
                self.H,
                cfg.stage1.init,
                cfg.model,
                always=always.to(self.device),
            )
            self._setup(g, *build_appearance(cfg, self.c0, self.device))

    def _setup(self, gauss: VideoGaussians, color: ColorMLP, tm: ToneMapper, bg: Background):
        check_gain(gauss, self.cfg, "stage 1")
        self.gauss, self.color, self.tm, self.bg = gauss, color, tm, bg
        lr = self.cfg.stage1.lr
        self.gauss_keys = gaussian_keys(gauss.params, GAUSSIAN_KEYS)
        self.optimizers = {
            **gaussian_optimizers(gauss.params, self.gauss_keys, lr),
            **module_optimizers({"color": color, "tonemap": tm, "background": bg}, lr),
        }
        self.strategy = Strategy(self.cfg.stage1.densify, self.gauss.layout(), seed=self.cfg.seed)
        self.dstate = self.strategy.initialize_state()
        self.knn.invalidate()

    # -- rendering
    # ----------------------------------------------------------------------------------------------
    def render(self, t: float, dest_times: Sequence[float] = ()) -> RenderResult:
        """Render the video Gaussians at time t with the Gaussians' positions at each destination
        time as features."""
        return render_gaussians(
            self.gauss,
            self.color,
            self.bg,
            t,
            self.viewmat,
            self.K,
            self.W,
            self.H,
            "ortho",
            self.backend,
            dest_times,
        )

    def tonemap(self, hdr: torch.Tensor, i: int) -> torch.Tensor:
        return self.tm(hdr, self.log2_dt[i])

    # -- the hooks of the shared iteration (m4dgs.training.stage.Stage)
    # ----------------------------------------------------------------------------------------------
    def camera_model(self) -> CameraModel:
        return self.camera

    def render_view(self, t, view, camera, dest_times=(), detach_camera=False) -> RenderResult:
        return self.render(t, dest_times)

    def trajectories(self) -> Trajectories:
        g = self.gauss
        return Trajectories(g.params["ctrl"], g.params["rot"], g.knots, g.num_frames, g.spline_memo)

    def gaussian_sets(self) -> List[GaussianSet]:
        return [
            GaussianSet(
                self.gauss.params, self._gauss_optimizers(), self.strategy, self.dstate, "n_"
            )
        ]

    def all_optimizers(self):
        return list(self.optimizers.values())

    def position_optimizers(self):
        return [self.optimizers["ctrl"]]

    def _gauss_optimizers(self):
        return {k: self.optimizers[k] for k in self.gauss_keys}

    # -- checkpoints
    # ----------------------------------------------------------------------------------------------
    def state_dict(self) -> Dict[str, Any]:
        return {
            "gaussians": self.gauss.to_state(),
            "color": self.color.state_dict(),
            "tonemap": self.tm.state_dict(),
            "background": self.bg.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "densify_state": self.dstate,
            "rng": self.rng.bit_generator.state,
            "strategy": self.strategy.state_dict(),
            "knn": self.knn.state_dict(),
            "log2_dt": self.log2_dt.cpu(),
        }

    def load_state_dict(self, sd: Dict[str, Any]) -> None:
        g = VideoGaussians.from_state(sd["gaussians"]).to(self.device)
        color, tm, bg = build_appearance(self.cfg, self.c0, self.device, pretrain=False)
        color.load_state_dict(sd["color"])
        tm.load_state_dict(sd["tonemap"])
        bg.load_state_dict(sd["background"])
        self._setup(g, color, tm, bg)
        for k, o in self.optimizers.items():
            o.load_state_dict(sd["optimizers"][k])
        self.dstate = sd["densify_state"]
        self.rng.bit_generator.state = sd["rng"]
        # checkpoints of older versions have neither: the run then resumes, but not bit for bit
        self.strategy.load_state_dict(sd.get("strategy", {}))
        self.knn.load_state_dict(sd.get("knn", {}))
        self.log2_dt = sd["log2_dt"].to(self.device)

    # -- outputs
    # ----------------------------------------------------------------------------------------------
    @torch.no_grad()
    def render_training_video(self) -> Dict[str, torch.Tensor]:
        """HDR [T, H, W, 3], LDR reconstructions [T, H, W, 3] at each frame's exposure, depth [T, H,
        W]."""
        hdr, ldr, dep = [], [], []
        for i in range(self.data.num_frames):
            r = self.render(float(i))
            hdr.append(r.hdr)
            ldr.append(self.tonemap(r.hdr, i).clamp(0, 1))
            dep.append(r.depth)
        return {"hdr": torch.stack(hdr), "ldr": torch.stack(ldr), "depth": torch.stack(dep)}


def train_stage1(
    stage: VideoStage,
    start: int = 0,
    on_step: Optional[Callable[[int, Dict[str, float]], None]] = None,
    progress: bool = True,
) -> None:
    """Run iterations start..iterations-1, calling on_step(it, record) after each (logging,
    checkpoints)."""
    train_loop(
        stage, stage.cfg.stage1.iterations, start, on_step, progress, "stage 1 (video Gaussians)"
    )
