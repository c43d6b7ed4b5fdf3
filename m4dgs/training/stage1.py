"""Stage 1: video HDR Gaussians in orthographic camera space (paper sec. 3.3.1, 3.3.3; appendix).

Fully dynamic Gaussians live in video space (x, y in [-1, 1] normalised image coordinates, z = prior
depth) and are rendered with the orthographic camera J_ortho = [[W/2, 0, 0], [0, H/2, 0]], so camera
and object motion are both Gaussian motion and no camera is needed. Each iteration samples a
training time t and renders, in ONE pass, the HDR image, depth, alpha and the Gaussians' positions
at destination times (extra feature channels) from which the rendered flow / track maps follow.
Losses (weights in `config.Stage1Config`): LDR RGB (0.8 L1 + 0.2 D-SSIM) through the learned tone
mapper, unit exposure, depth L1, flow (t' = t +- N_e) or track (random t') loss, ARAP, velocity and
acceleration smoothness, and temporal luminance regularisation after densification. Only training
LDR frames, their exposure times and the priors are used, never ground truth."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional

import numpy as np
import torch

from m4dgs.core import camera as cam
from m4dgs.core import rotation as rot
from m4dgs.core import spline
from m4dgs.core.crf import get_crf, log_logistic, reinhard_anchored
from m4dgs.losses.geometry import depth_loss, flow_from_destination_map, flow_loss, track_loss
from m4dgs.losses.motion import acceleration_loss, knn, velocity_loss
from m4dgs.losses.photometric import rgb_loss, unit_exposure_loss
from m4dgs.losses.temporal import tlr_loss, tlr_valid_mask
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import VideoGaussians, init_video_gaussians
from m4dgs.model.tonemap import ToneMapper, monotonicity_penalty, pretrain_tonemapper
from m4dgs.raster import render
from m4dgs.training.config import TrainConfig
from m4dgs.training.data import TrainingData
from m4dgs.training.densify import Strategy
from m4dgs.training.exposure import perturb_exposures

GAUSSIAN_KEYS = ("ctrl", "rot", "scales", "opacities", "features")


def build_appearance(cfg: TrainConfig, c0: float, device, pretrain: bool = True) -> tuple:
    """Colour MLP (36 -> 36 -> 3, 2^x output) and the per-channel tone mapper, pre-trained on a
    generic curve."""
    color = ColorMLP(
        feature_dim=cfg.model.feature_dim, hidden=cfg.tonemap.color_hidden, view_dependent=False
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


class Background(torch.nn.Module):
    """Constant HDR background colour 2^b behind the Gaussians (b learnable when enabled)."""

    def __init__(self, learn: bool = True, init_log2: float = -4.0):
        super().__init__()
        self.log2 = torch.nn.Parameter(torch.full((3,), float(init_log2)), requires_grad=learn)

    def forward(self) -> torch.Tensor:
        return torch.exp2(self.log2)


def make_optimizers(
    params: Dict[str, torch.nn.Parameter], lr, extra_modules: Dict[str, torch.nn.Module]
) -> Dict[str, torch.optim.Optimizer]:
    """One Adam per Gaussian attribute (so densification can edit rows) and one per MLP."""
    lrs = {
        "ctrl": lr.position_init,
        "means": lr.position_init,
        "rot": lr.rotation,
        "quats": lr.rotation,
        "scales": lr.scale,
        "opacities": lr.opacity,
        "features": lr.features,
    }
    opts = {k: torch.optim.Adam([p], lr=lrs[k], eps=lr.adam_eps) for k, p in params.items()}
    for name, m in extra_modules.items():
        opts[name] = torch.optim.Adam(m.parameters(), lr=lr.mlp, eps=lr.adam_eps)
    return opts


@dataclass
class RenderResult:
    hdr: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W]
    alpha: torch.Tensor  # [H, W]
    # destination-position maps [H, W, 3], one per requested destination time
    dest: List[torch.Tensor]
    meta: Any


class VideoStage:
    """Stage-1 model + optimisation state. `step(it)` runs one iteration; `state_dict()` /
    `load_state_dict()` resume."""

    def __init__(
        self,
        data: TrainingData,
        cfg: TrainConfig,
        device="cpu",
        backend: str = "auto",
        init: bool = True,
    ):
        self.data, self.cfg, self.device, self.backend = data, cfg, torch.device(device), backend
        s1 = cfg.stage1
        self.W, self.H = data.width, data.height
        self.K = torch.tensor(cam.K_ortho(self.W, self.H), dtype=torch.float32, device=self.device)
        self.viewmat = torch.eye(4, dtype=torch.float32, device=self.device)
        self.c0 = float(cfg.exposure.unit_exposure_value or data.unit_exposure_value)
        log2_dt = data.log2_dt.to(self.device)
        if cfg.exposure.perturb_ev > 0:
            log2_dt = perturb_exposures(log2_dt, cfg.exposure.perturb_ev, cfg.exposure.perturb_seed)
        self.log2_dt = log2_dt
        self.rng = np.random.default_rng(cfg.seed)
        self.gauss: Optional[VideoGaussians] = None
        if init:
            g = init_video_gaussians(
                data.tracks.to(self.device),
                data.track_vis.to(self.device),
                data.depth.to(self.device),
                self.W,
                self.H,
                s1.init,
                cfg.model,
            )
            self._setup(g, *build_appearance(cfg, self.c0, self.device))

    def _setup(self, gauss: VideoGaussians, color: ColorMLP, tm: ToneMapper, bg: "Background"):
        self.gauss, self.color, self.tm, self.bg = gauss, color, tm, bg
        self.optimizers = make_optimizers(
            self.gauss.params, self.cfg.stage1.lr, {"color": color, "tonemap": tm, "background": bg}
        )
        self.strategy = Strategy(self.cfg.stage1.densify, self.gauss.layout(), seed=self.cfg.seed)
        self.dstate = self.strategy.initialize_state()
        self._knn_cache = None

    # -- rendering
    # ----------------------------------------------------------------------------------------------
    def render(self, t: float, dest_times=(), colour: bool = True) -> RenderResult:
        """Render the video Gaussians at time t with the Gaussians' positions at each destination
        time as features."""
        g = self.gauss
        means = g.positions(t)
        feats = [self.color(g.features())] if colour else [means.new_zeros(means.shape[0], 3)]
        feats += [g.positions(float(d)) for d in dest_times]
        feats = torch.cat(feats, -1)
        background = torch.cat(
            [self.bg() if colour else means.new_zeros(3), means.new_zeros(feats.shape[1] - 3)]
        )
        out = render(
            means,
            g.quats(t),
            g.scales(),
            g.opacities(),
            feats,
            self.viewmat,
            self.K,
            self.W,
            self.H,
            camera_model="ortho",
            backend=self.backend,
            background=background,
        )
        f = out.features
        dest = [f[..., 3 + 3 * i : 6 + 3 * i] for i in range(len(dest_times))]
        return RenderResult(f[..., :3], out.depth[..., 0], out.alpha[..., 0], dest, out.meta)

    def tonemap(self, hdr: torch.Tensor, i: int) -> torch.Tensor:
        return self.tm(hdr, self.log2_dt[i])

    # -- one iteration
    # ----------------------------------------------------------------------------------------------
    def _arap_neighbours(self, pos: torch.Tensor, it: int) -> torch.Tensor:
        n = pos.shape[0]
        if self._knn_cache is None or self._knn_cache[0] != n or it - self._knn_cache[1] >= 100:
            self._knn_cache = (n, it, knn(pos.detach(), self.cfg.stage1.arap_k)[0])
        return self._knn_cache[2]

    def losses(self, it: int) -> Dict[str, torch.Tensor]:
        cfg, s1, d = self.cfg, self.cfg.stage1, self.data
        T = d.num_frames
        i = int(self.rng.integers(T))
        flow_targets = d.flow_targets(i) if d.flow is not None else []
        use_flow = bool(flow_targets) and self.rng.random() < s1.flow_prob
        j = (
            int(self.rng.choice(flow_targets))
            if use_flow
            else int(self.rng.choice([k for k in range(T) if k != i]))
            if T > 1
            else i
        )
        tlr_on = cfg.ablation.tlr and s1.lambda_tlr > 0 and it >= s1.tlr_start_step()
        nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T] if tlr_on else []
        r = self.render(float(i), [float(j)] + [float(k) for k in nbrs])
        L: Dict[str, torch.Tensor] = {}
        ldr = self.tonemap(r.hdr, i)
        L["rgb"] = rgb_loss(ldr, d.ldr[i], lambda_d=s1.lambda_dssim)
        L["ue"] = unit_exposure_loss(self.tm.unit_exposure_value(), self.c0)
        if cfg.ablation.depth_loss and s1.lambda_dep > 0:
            L["dep"] = depth_loss(r.depth, d.depth[i], valid=r.alpha.detach() > 0.5)
        if cfg.ablation.track_loss and s1.lambda_track > 0 and j != i:
            if use_flow:
                p = d.flow_index(i, j)
                pred, v = flow_from_destination_map(r.dest[0], alpha=r.alpha)
                L["track"] = flow_loss(pred, d.flow[p], d.flow_valid[p] & v, norm="l1")
            else:
                vis = d.track_vis[:, i] & d.track_vis[:, j]
                if bool(vis.any()):
                    L["track"] = track_loss(
                        r.dest[0], d.tracks[vis, i], d.tracks[vis, j], alpha=r.alpha, norm="l1"
                    )
        # motion regularisers on a random subset of Gaussians
        g = self.gauss
        n = g.num_gaussians
        sub = torch.from_numpy(self.rng.choice(n, size=min(n, 4096), replace=False)).to(self.device)
        if s1.lambda_arap > 0 and n > s1.arap_k:
            pos_t = g.positions(float(i))
            t2 = float(self.rng.integers(T))
            nbr = self._arap_neighbours(pos_t, it)
            L["arap"] = _arap_subset(pos_t, g.positions(t2), nbr, sub)
        if (s1.lambda_vel > 0 or s1.lambda_acc > 0) and T > 2:
            w = s1.smooth_window
            times = torch.arange(
                max(0, i - w - 1), min(T, i + w + 2), dtype=torch.float32, device=self.device
            )
            if times.numel() >= 3:
                # [W, n, 3]
                pos = spline.evaluate(g.params["ctrl"][sub], g.knots, times).transpose(0, 1)
                q = rot.poly_evaluate(
                    g.params["rot"][sub], rot.normalize_time(times, g.num_frames), normalize=True
                ).transpose(0, 1)
                L["vel"] = velocity_loss(pos, q)
                L["acc"] = acceleration_loss(pos, q)
        if nbrs:
            terms = []
            for k_idx, k in enumerate(nbrs):
                with torch.no_grad():
                    rn = self.render(float(k))
                flow, fvalid = flow_from_destination_map(
                    r.dest[1 + k_idx].detach(), alpha=r.alpha.detach()
                )
                zref = (r.dest[1 + k_idx].detach() / r.alpha.detach().clamp_min(1e-6)[..., None])[
                    ..., 2
                ]
                valid = fvalid & tlr_valid_mask(flow, rn.depth, zref, ratio=s1.tlr_occlusion_ratio)
                terms.append(tlr_loss(r.hdr, rn.hdr, flow, valid))
            L["tlr"] = torch.stack(terms).mean()
        if cfg.tonemap.lambda_monotonic > 0:
            L["mono"] = monotonicity_penalty(self.tm)
        if s1.lambda_opacity > 0:
            L["opacity"] = (1.0 - g.opacities()).mean()
        if s1.lambda_scale_std > 0:
            L["scale_std"] = g.scales().std(dim=-1).mean()
        self._last_meta = r.meta
        return L

    def weights(self) -> Dict[str, float]:
        s1, tm = self.cfg.stage1, self.cfg.tonemap
        return {
            "rgb": s1.lambda_rgb,
            "ue": s1.lambda_ue,
            "dep": s1.lambda_dep,
            "track": s1.lambda_track,
            "arap": s1.lambda_arap,
            "vel": s1.lambda_vel,
            "acc": s1.lambda_acc,
            "tlr": s1.lambda_tlr,
            "mono": tm.lambda_monotonic,
            "opacity": s1.lambda_opacity,
            "scale_std": s1.lambda_scale_std,
        }

    def step(self, it: int) -> Dict[str, float]:
        s1 = self.cfg.stage1
        for o in self.optimizers.values():
            o.zero_grad(set_to_none=True)
        lr = s1.lr.position_lr(it, s1.iterations)
        for group in self.optimizers["ctrl"].param_groups:
            group["lr"] = lr
        L = self.losses(it)
        w = self.weights()
        total = sum(w[k] * v for k, v in L.items())
        info = {
            "means2d": self._last_meta.means2d,
            "radii": self._last_meta.radii,
            "width": self.W,
            "height": self.H,
        }
        self.strategy.step_pre_backward(self.gauss.params, self.optimizers, self.dstate, it, info)
        total.backward()
        for o in self.optimizers.values():
            o.step()
        counts = self.strategy.step_post_backward(
            self.gauss.params, self._gauss_optimizers(), self.dstate, it, info
        )
        if any(counts.values()):
            self._knn_cache = None
        rec = {k: float(v.detach()) for k, v in L.items()}
        rec["total"] = float(total.detach())
        rec["num_gaussians"] = self.gauss.num_gaussians
        rec.update({f"n_{k}": v for k, v in counts.items() if v})
        return rec

    def _gauss_optimizers(self):
        return {k: self.optimizers[k] for k in GAUSSIAN_KEYS}

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


def _arap_subset(
    pos_t: torch.Tensor, pos_t2: torch.Tensor, nbr: torch.Tensor, sub: torch.Tensor
) -> torch.Tensor:
    """ARAP on a subset of Gaussians: distances to their k nearest neighbours (indices into the full
    set)."""
    idx = nbr[sub]  # [n, k]
    d_t = (pos_t[sub][:, None] - pos_t[idx]).norm(dim=-1)
    d_t2 = (pos_t2[sub][:, None] - pos_t2[idx]).norm(dim=-1)
    return ((d_t - d_t2) ** 2).mean()


def train_loop(
    stage,
    iterations: int,
    start: int = 0,
    on_step: Optional[Callable[[int, Dict[str, float]], None]] = None,
    progress: bool = True,
    desc: str = "",
    postfix_keys=("rgb",),
) -> None:
    """Run stage.step(it) for it in start..iterations-1 with a progress bar (loss, Gaussian count)
    and a callback after each step (logging, checkpoints). Shared by both stages."""
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=iterations, initial=start, desc=desc, unit="it", dynamic_ncols=True)
    for it in range(start, iterations):
        t0 = time.perf_counter()
        rec = stage.step(it)
        rec["sec"] = time.perf_counter() - t0
        if on_step is not None:
            on_step(it, rec)
        if bar is not None:
            bar.update(1)
            if it % 10 == 0 or it == iterations - 1:
                post = {
                    "loss": f"{rec['total']:.4f}",
                    **{k: f"{rec[k]:.4f}" for k in postfix_keys if k in rec},
                    "N": rec["num_gaussians"],
                }
                if "num_dynamic" in rec:
                    post["dyn"] = rec["num_dynamic"]
                bar.set_postfix(post)
    if bar is not None:
        bar.close()


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
