"""Stage 2: static + dynamic world Gaussians with joint camera refinement (paper sec. 3.3.2-3.3.3,
appendix).

World Gaussians (the union of a static set and a dynamic spline set, from the video-to-world
transform or, for the "no video init" ablation and the world-only baselines, from lifted tracks) are
rendered with a pinhole camera whose per-frame pose corrections are optimised jointly. Losses
(m4dgs.training.objective, weights in `config.Stage2Config.loss`): every stage-1 loss (now with
pinhole flow/track maps and the depth prior mapped to world depth by the bundle-adjustment depth
scales) plus this stage's own term, the HDR photometric reprojection loss against the stage-1 HDR
renders (stopped gradients, t' in {t +- 1, t +- 2}, static pixels only; `hdr_reprojection_term`).
Static and dynamic Gaussians have their own densification schedules; mistakenly densified dynamic
Gaussians are removed periodically by re-running the dynamic/static identification on their
projected trajectories (`WorldStage.after_step`)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Sequence

import numpy as np
import torch

from m4dgs.core import camera as cam
from m4dgs.core import spline
from m4dgs.losses.temporal import hdr_reprojection_loss, ldr_reprojection_loss
from m4dgs.model.background import Background
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import WorldGaussians
from m4dgs.model.render import RenderResult, render_world
from m4dgs.model.tonemap import ToneMapper
from m4dgs.training.config import TrainConfig, validate
from m4dgs.training.data import TrainingData, depth_data
from m4dgs.training.densify import Strategy
from m4dgs.training.objective import CameraModel, FrameSample, Term, Trajectories
from m4dgs.training.stage import (
    SPLINE_KEYS,
    STATIC_KEYS,
    GaussianSet,
    Stage,
    adam,
    check_gain,
    gaussian_keys,
    gaussian_optimizers,
    module_optimizers,
    train_loop,
)

DYNAMIC_KEYS = SPLINE_KEYS


def axis_angle_to_rotmat(w: torch.Tensor) -> torch.Tensor:
    """Rodrigues: [..., 3] axis-angle -> [..., 3, 3] rotation (stable at 0 through the Taylor
    terms)."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]
    theta = theta2.clamp_min(1e-20).sqrt()
    small = theta2 < 1e-8
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2.clamp_min(1e-20))
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    Kx = torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*w.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(Kx)
    return eye + a * Kx + b * (Kx @ Kx)


class CameraRig(torch.nn.Module):
    """Per-frame camera poses as fixed initial c2w times a learnable right correction (rotation,
    translation)."""

    def __init__(self, K: torch.Tensor, c2w_init: torch.Tensor):
        super().__init__()
        T = c2w_init.shape[0]
        self.register_buffer("K", K.float())
        self.register_buffer("c2w_init", c2w_init.float())
        self.dw = torch.nn.Parameter(torch.zeros(T, 3, device=c2w_init.device))
        self.dt = torch.nn.Parameter(torch.zeros(T, 3, device=c2w_init.device))

    def c2w(self) -> torch.Tensor:
        """[T, 4, 4] current camera-to-world poses."""
        R = self.c2w_init[:, :3, :3] @ axis_angle_to_rotmat(self.dw)
        t = self.c2w_init[:, :3, 3] + (self.c2w_init[:, :3, :3] @ self.dt[..., None])[..., 0]
        top = torch.cat([R, t[..., None]], -1)
        bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], device=R.device).expand(R.shape[0], 1, 4)
        return torch.cat([top, bottom], -2)


@dataclass
class WorldInit:
    """What stage 2 starts from (the V2W transform or lifted priors, camera initialisation and
    stage 1): the world Gaussians and appearance modules, the bundle-adjusted cameras (K [3, 3],
    c2w [T, 4, 4]) and per-frame depth-prior scales [T], the dynamic masks [T, H, W] (None: no
    removal of misplaced dynamic Gaussians, no masking of L_pr) and the stage-1 HDR training frames
    [T, H, W, 3] (None: no HDR reprojection loss)."""

    gauss: WorldGaussians
    color: ColorMLP
    tonemap: ToneMapper
    background: Background
    K: torch.Tensor
    c2w: torch.Tensor
    depth_scale: torch.Tensor
    dynamic_masks: Optional[torch.Tensor] = None
    stage1_hdr: Optional[torch.Tensor] = None


class WorldStage(Stage):
    """Stage-2 model + optimisation state; `step(it)` runs one iteration
    (m4dgs.training.stage.Stage), `state_dict()`/`load_state_dict()` resume. The method
    (cfg.method) picks the variant: "ldr-reproj" replaces L_pr by the LDR reprojection loss of the
    baselines, "static-hdr" keeps every Gaussian static and the cameras fixed."""

    section = "stage2"

    def __init__(
        self,
        data: TrainingData,
        cfg: TrainConfig,
        init: WorldInit,
        device="cpu",
        backend: str = "auto",
    ):
        validate(cfg)
        data = depth_data(data, cfg.stage1.init)  # the clip's depth prior, or held along chains
        super().__init__(data, cfg, device, backend, seed=cfg.seed + 1)
        self.depth_scale = init.depth_scale.float().to(self.device)
        masks = init.dynamic_masks
        self.dynamic_masks = None if masks is None else masks.bool().to(self.device)
        hdr = init.stage1_hdr
        self.stage1_hdr = None if hdr is None else hdr.float().to(self.device)
        self.ldr_reproj = cfg.method == "ldr-reproj"
        self.static_only = cfg.method == "static-hdr"
        self.rig = CameraRig(init.K.to(self.device), init.c2w.to(self.device))
        # position learning rates scale with the scene extent (3DGS); extent = median world depth
        d = data.depth.to(self.device) * self.depth_scale[:, None, None]
        self.extent = float(d[d > 0].median()) if bool((d > 0).any()) else 1.0
        self.camera_extent = camera_extent(init.c2w, self.extent)
        self._setup(
            init.gauss.to(self.device),
            init.color.to(self.device),
            init.tonemap.to(self.device),
            init.background.to(self.device),
        )

    def _setup(self, gauss: WorldGaussians, color, tm, bg):
        s2 = self.cfg.stage2
        check_gain(gauss, self.cfg, "stage 2")
        self.gauss, self.color, self.tm, self.bg = gauss, color, tm, bg
        lr = s2.lr
        self.opt_static = gaussian_optimizers(
            gauss.static, gaussian_keys(gauss.static, STATIC_KEYS), lr, self.extent
        )
        self.opt_dynamic = gaussian_optimizers(
            gauss.dynamic, gaussian_keys(gauss.dynamic, DYNAMIC_KEYS), lr, self.extent, dynamic=True
        )
        self.opt_other = {
            **module_optimizers({"color": color, "tonemap": tm, "background": bg}, lr),
            "camera": adam(
                [
                    {"params": [self.rig.dw], "lr": lr.camera_rotation},
                    {"params": [self.rig.dt], "lr": lr.camera_translation * self.extent},
                ],
                lr.camera_rotation,
                lr.adam_eps,
            ),
        }
        ext = self.camera_extent if s2.clone_split_extent == "cameras" else 1.0
        self.strat_static = Strategy(
            s2.densify_static, gauss.static_layout(), seed=self.cfg.seed, extent=ext
        )
        self.strat_dynamic = Strategy(
            s2.densify_dynamic, gauss.dynamic_layout(), seed=self.cfg.seed + 7, extent=ext
        )
        self.state_static = self.strat_static.initialize_state()
        self.state_dynamic = self.strat_dynamic.initialize_state()
        self.knn.invalidate()

    @property
    def optimize_cameras(self) -> bool:
        return self.cfg.stage2.optimize_cameras and not self.static_only

    def cameras(self) -> torch.Tensor:
        c = self.rig.c2w()
        return c if self.optimize_cameras else c.detach()

    # -- rendering
    # ----------------------------------------------------------------------------------------------
    def render_at(
        self,
        t: float,
        c2w: torch.Tensor,
        K: Optional[torch.Tensor] = None,
        width: Optional[int] = None,
        height: Optional[int] = None,
        dest_times=(),
    ) -> RenderResult:
        """Render at time t from camera c2w [4, 4]; features: HDR colour + world positions at each
        destination time."""
        return render_world(
            self.gauss,
            self.color,
            self.bg,
            t,
            c2w,
            self.rig.K if K is None else K,
            width or self.W,
            height or self.H,
            self.backend,
            dest_times,
        )

    # -- the hooks of the shared iteration (m4dgs.training.stage.Stage)
    # ----------------------------------------------------------------------------------------------
    @property
    def motion(self) -> bool:
        return not self.static_only

    def camera_model(self) -> CameraModel:
        c2w = self.cameras()
        return CameraModel(self.rig.K, c2w, cam.invert_rigid(c2w), self.depth_scale, self.extent)

    def render_view(
        self,
        t: float,
        view: int,
        camera: CameraModel,
        dest_times: Sequence[float] = (),
        detach_camera: bool = False,
    ) -> RenderResult:
        c2w = camera.c2w[view]
        return self.render_at(t, c2w.detach() if detach_camera else c2w, dest_times=dest_times)

    def trajectories(self) -> Trajectories:
        g = self.gauss
        return Trajectories(
            g.dynamic["ctrl"], g.dynamic["rot"], g.knots, g.num_frames, g.spline_memo
        )

    def stage_terms(
        self, it: int, sample: FrameSample, r: RenderResult, camera: CameraModel
    ) -> List[Term]:
        """The photometric reprojection term "pr" while it is active (stage2.pr_steps) and the
        cameras are optimised: the HDR one against the stage-1 frames (paper), or the LDR one of
        the ldr-reproj baselines."""
        s2, d, i = self.cfg.stage2, self.data, sample.i
        T = d.num_frames
        if not ((s2.pr_steps is None or it < s2.pr_steps) and self.optimize_cameras):
            return []
        mask = None if self.dynamic_masks is None else self.dynamic_masks[i]
        if self.ldr_reproj:
            refs = ldr_reprojection_refs(i, T, d.num_levels, s2.ldr_reproj_pairs)
            if refs:
                return [
                    ldr_reprojection_term(d.ldr, i, refs, r.depth, self.rig.K, camera.c2w, mask)
                ]
        elif self.cfg.ablation.reproj_loss and self.stage1_hdr is not None and s2.lambda_pr > 0:
            refs = [i + o for off in s2.pr_offsets for o in (-off, off) if 0 <= i + o < T]
            if refs:
                query = self.stage1_hdr[i] if s2.pr_query == "stage1" else r.hdr
                return [
                    hdr_reprojection_term(
                        query, self.stage1_hdr, i, refs, r.depth, self.rig.K, camera.c2w, mask
                    )
                ]
        return []

    def stage_weights(self) -> Dict[str, float]:
        return {"pr": self.cfg.stage2.lambda_pr}

    def gaussian_sets(self) -> List[GaussianSet]:
        g = self.gauss
        return [
            GaussianSet(g.static, self.opt_static, self.strat_static, self.state_static, "static_"),
            GaussianSet(
                g.dynamic,
                self.opt_dynamic,
                self.strat_dynamic,
                self.state_dynamic,
                "dynamic_",
                active=not self.static_only,
            ),
        ]

    def split_render_info(self, info: Dict[str, Any]) -> List[Dict[str, Any]]:
        return list(self.gauss.split_render_info(info))

    def all_optimizers(self):
        return (
            list(self.opt_static.values())
            + list(self.opt_dynamic.values())
            + list(self.opt_other.values())
        )

    def position_optimizers(self):
        return [self.opt_static["means"], self.opt_dynamic["ctrl"]]

    def position_lrs(self, it: int):
        """Static means: the 3DGS decay; dynamic control points: their own (LRConfig
        dynamic_position_*; appendix "Implementation Details"); both x the scene extent."""
        lr, n = self.cfg.stage2.lr, self.cfg.stage2.iterations
        return [
            (self.opt_static["means"], lr.position_lr(it, n) * self.extent),
            (self.opt_dynamic["ctrl"], lr.position_lr(it, n, dynamic=True) * self.extent),
        ]

    def record(self) -> Dict[str, Any]:
        return {"num_gaussians": self.gauss.num_gaussians, "num_dynamic": self.gauss.num_dynamic}

    def after_step(self, it: int) -> Dict[str, int]:
        """Remove mistakenly densified dynamic Gaussians every stage2.dynamic_removal_every steps
        while the dynamic set densifies (appendix; counts "dynamic_removal_tested" / "_removed" /
        "_kept" in the run log) and the near-camera floaters (not in the paper;
        stage2.near_camera_fraction). A removal pass invalidates the kNN cache."""
        s2 = self.cfg.stage2
        counts = {}
        if (
            not self.static_only
            and s2.dynamic_removal_every > 0
            and it > 0
            and it % s2.dynamic_removal_every == 0
            and it <= s2.densify_dynamic.stop_iter
            and self.dynamic_masks is not None
        ):
            counts.update(self.remove_misplaced_dynamic(it))
        if (
            not self.static_only
            and s2.near_camera_fraction > 0
            and it > 0
            and (
                (s2.dynamic_removal_every > 0 and it % s2.dynamic_removal_every == 0)
                or it == s2.iterations - 1
            )
        ):
            counts["dynamic_near_removed"] = self.remove_near_camera_dynamic()
        if counts:
            self.knn.invalidate()
        return counts

    def removal_candidates(self) -> torch.Tensor:
        """[N_dyn] bool: the dynamic Gaussians the removal pass tests
        (stage2.dynamic_removal_scope): "new" those created by densification since the previous
        pass, "densified" every one created by densification, "all" every dynamic Gaussian."""
        scope, n = self.cfg.stage2.dynamic_removal_scope, self.gauss.num_dynamic
        if scope == "all":
            return torch.ones(n, dtype=torch.bool, device=self.device)
        born = Strategy.born(self.state_dynamic, n, self.device)
        last = int(self.state_dynamic.get("last_removal", -1)) if scope == "new" else -1
        return born > last

    @torch.no_grad()
    def remove_misplaced_dynamic(self, it: int = 0) -> Dict[str, int]:
        """Re-run the V2W dynamic/static identification (N_d / N_f > v2w.dynamic_ratio, occlusion
        test unless ablation.occlusion_handling_removal is off) on the projected trajectories of the
        candidate dynamic Gaussians (`removal_candidates`) and remove the ones identified as static
        (appendix "Gaussian Densification": mistakenly densified dynamic Gaussians). At most
        stage2.dynamic_removal_max_fraction of the dynamic set goes in one pass (the fewest N_d
        first, with a warning), never all of it. Returns the counts for the run log:
        dynamic_removal_tested / _removed / _kept (tested - removed) and, when the guard cut the
        removal, dynamic_removal_capped = the number identified as static."""
        from m4dgs.training.v2w import dynamic_counts

        s2, g = self.cfg.stage2, self.gauss
        n = g.num_dynamic
        cand = (
            self.removal_candidates() if n else torch.zeros(0, dtype=torch.bool, device=self.device)
        )
        self.state_dynamic["last_removal"] = it
        idx = torch.where(cand)[0]
        counts = {"dynamic_removal_tested": int(idx.numel()), "dynamic_removal_removed": 0}
        if idx.numel() == 0:
            counts["dynamic_removal_kept"] = 0
            return counts
        T = self.data.num_frames
        c2w = self.cameras().detach()
        pos = spline.evaluate(
            g.dynamic["ctrl"][idx],
            g.knots,
            torch.arange(T, dtype=torch.float32, device=self.device),
        )
        pv = torch.stack(
            [
                cam.camera_to_video(
                    cam.transform_points(cam.invert_rigid(c2w[t]), pos[:, t]),
                    self.rig.K,
                    self.W,
                    self.H,
                )
                for t in range(T)
            ],
            1,
        )
        occlusion = self.cfg.ablation.occlusion_handling_removal
        depth = (
            torch.stack([self.render_at(float(t), c2w[t]).depth for t in range(T)])
            if occlusion
            else None
        )
        nd = dynamic_counts(
            pv,
            self.dynamic_masks,
            depth,
            self.W,
            self.H,
            occlusion_handling=occlusion,
            occlusion_tol=self.cfg.v2w.occlusion_tol,
        )
        static = nd.double() / float(max(T, 1)) <= float(self.cfg.v2w.dynamic_ratio)
        n_static = int(static.sum())
        cap = min(int(math.floor(s2.dynamic_removal_max_fraction * n)), n - 1)
        sel = idx[static]
        if n_static > cap:
            order = torch.argsort(nd[static].float(), stable=True)
            sel = sel[order[: max(cap, 0)]]
            counts["dynamic_removal_capped"] = n_static
            warnings.warn(
                f"stage 2 step {it}: the removal of mistakenly densified dynamic Gaussians "
                f"identified {n_static} of {n} as static; removing only {sel.numel()} "
                f"(stage2.dynamic_removal_max_fraction = {s2.dynamic_removal_max_fraction})",
                RuntimeWarning,
                stacklevel=2,
            )
        remove = torch.zeros(n, dtype=torch.bool, device=self.device)
        remove[sel] = True
        removed = self.strat_dynamic.remove(g.dynamic, self.opt_dynamic, self.state_dynamic, remove)
        counts["dynamic_removal_removed"] = removed
        counts["dynamic_removal_kept"] = counts["dynamic_removal_tested"] - removed
        return counts

    @torch.no_grad()
    def remove_near_camera_dynamic(self) -> int:
        """Remove the dynamic Gaussians that come in view closer than stage2.near_camera_fraction x
        the scene extent (median world depth) to the camera at a training time or between two
        (cameras interpolated as for the test frames). Returns the number removed (never the whole
        dynamic set)."""
        s2, g = self.cfg.stage2, self.gauss
        if g.num_dynamic == 0:
            return 0
        T = self.data.num_frames
        ts = np.arange(0, (T - 1) * s2.near_camera_samples + 1) / max(s2.near_camera_samples, 1)
        c2w = self.cameras().detach()
        poses = cam.interpolate_trajectory(
            np.arange(T, dtype=np.float64), c2w.cpu().double().numpy(), ts
        )
        times = torch.as_tensor(ts, dtype=g.knots.dtype, device=self.device)
        poses = torch.as_tensor(poses, dtype=g.knots.dtype, device=self.device)
        ctrl = g.dynamic["ctrl"]
        near = torch.cat(
            [  # chunks of Gaussians: [chunk, S, 3] positions at a time
                near_camera_gaussians(
                    spline.evaluate(ctrl[i : i + 16384], g.knots, times),
                    poses,
                    self.rig.K,
                    self.W,
                    self.H,
                    s2.near_camera_fraction * self.extent,
                )
                for i in range(0, ctrl.shape[0], 16384)
            ]
        )
        if bool(near.all()) or not bool(near.any()):
            return 0
        return self.strat_dynamic.remove(g.dynamic, self.opt_dynamic, self.state_dynamic, near)

    # -- checkpoints
    # ----------------------------------------------------------------------------------------------
    def state_dict(self) -> Dict[str, Any]:
        return {
            "gaussians": self.gauss.to_state(),
            "color": self.color.state_dict(),
            "tonemap": self.tm.state_dict(),
            "background": self.bg.state_dict(),
            "rig": self.rig.state_dict(),
            "opt_static": {k: o.state_dict() for k, o in self.opt_static.items()},
            "opt_dynamic": {k: o.state_dict() for k, o in self.opt_dynamic.items()},
            "opt_other": {k: o.state_dict() for k, o in self.opt_other.items()},
            "state_static": self.state_static,
            "state_dynamic": self.state_dynamic,
            "rng": self.rng.bit_generator.state,
            "strategy_static": self.strat_static.state_dict(),
            "strategy_dynamic": self.strat_dynamic.state_dict(),
            "knn": self.knn.state_dict(),
        }

    def load_state_dict(self, sd: Dict[str, Any]) -> None:
        self.rig.load_state_dict(sd["rig"])
        self.color.load_state_dict(sd["color"])
        self.tm.load_state_dict(sd["tonemap"])
        self.bg.load_state_dict(sd["background"])
        self._setup(
            WorldGaussians.from_state(sd["gaussians"]).to(self.device), self.color, self.tm, self.bg
        )
        for name, opts in (
            ("opt_static", self.opt_static),
            ("opt_dynamic", self.opt_dynamic),
            ("opt_other", self.opt_other),
        ):
            for k, o in opts.items():
                o.load_state_dict(sd[name][k])
        self.state_static, self.state_dynamic = sd["state_static"], sd["state_dynamic"]
        self.rng.bit_generator.state = sd["rng"]
        # checkpoints of older versions have none of these: the run then resumes, not bit for bit
        self.strat_static.load_state_dict(sd.get("strategy_static", {}))
        self.strat_dynamic.load_state_dict(sd.get("strategy_dynamic", {}))
        self.knn.load_state_dict(sd.get("knn", {}))


def camera_extent(c2w: torch.Tensor, fallback: float = 1.0) -> float:
    """The 3DGS scene extent of cameras c2w [T, 4, 4] (getNerfppNorm's radius): 1.1 x the largest
    distance of a camera centre from their mean; `fallback` when the cameras do not move."""
    centres = c2w[:, :3, 3].double()
    r = 1.1 * float((centres - centres.mean(0)).norm(dim=-1).max()) if len(centres) else 0.0
    return r if r > 1e-6 else float(fallback)


def ldr_reprojection_refs(
    i: int, num_frames: int, num_levels: int, pairs: str = "same-exposure"
) -> list:
    """Training-frame indices t' paired with frame i by the LDR reprojection baselines (those inside
    the clip).

    pairs: "same-exposure" -> i +- N_e (N_e = num_levels, the observed exposure levels): the same
    level in an
        alternating schedule, so plain L1 between the LDR frames is meaningful; "consecutive" -> i
        +- 1: the neighbouring, differently exposed frames, where the L1 compares unequal exposures
        (SplineGS-HDR as the paper ran it). With one level both are i +- 1.
    """
    if pairs == "same-exposure":
        off = max(int(num_levels), 1)
    elif pairs == "consecutive":
        off = 1
    else:
        raise ValueError(f"unknown LDR reprojection pairs {pairs!r} (same-exposure | consecutive)")
    return [k for k in (i - off, i + off) if 0 <= k < num_frames]


def hdr_reprojection_term(
    query: torch.Tensor,
    hdr_frames: torch.Tensor,
    i: int,
    refs: Sequence[int],
    depth: torch.Tensor,
    K: torch.Tensor,
    c2w: torch.Tensor,
    mask: Optional[torch.Tensor] = None,
) -> Term:
    """L_pr (appendix "HDR Photometric Reprojection Loss"): the HDR image at t (`query`) against
    the stage-1 HDR frames hdr_frames[t'] warped into view i through the rendered depth and the
    cameras c2w [T, 4, 4], averaged over t' in `refs`; static pixels only (mask = dynamic)."""
    return "pr", torch.stack(
        [hdr_reprojection_loss(query, hdr_frames[k], depth, K, c2w[i], c2w[k], mask) for k in refs]
    ).mean()


def ldr_reprojection_term(
    ldr_frames: torch.Tensor,
    i: int,
    refs: Sequence[int],
    depth: torch.Tensor,
    K: torch.Tensor,
    c2w: torch.Tensor,
    mask: Optional[torch.Tensor] = None,
) -> Term:
    """The LDR reprojection loss of the ldr-reproj baselines: input frame i against the input frames
    t' in `refs` warped into view i, averaged (named "pr" like the HDR term it replaces)."""
    return "pr", torch.stack(
        [
            ldr_reprojection_loss(ldr_frames[i], ldr_frames[k], depth, K, c2w[i], c2w[k], mask)
            for k in refs
        ]
    ).mean()


def near_camera_gaussians(
    positions: torch.Tensor,
    c2w: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    z_min: float,
    margin: float = 0.5,
) -> torch.Tensor:
    """[N] bool: Gaussians that, at some sample s, are in front of camera s at depth z < z_min and
    project inside the image enlarged by `margin` x its size on every side (a near Gaussian just
    outside the frame still splats in).

    Args:
        positions: [N, S, 3] world means at S sample times; c2w: [S, 4, 4] cameras at those times
        (OpenCV); K: [3, 3] intrinsics; width, height: image size in pixels; z_min: camera-space
        depth (world units).
    """
    # [N, S, 3], broadcast over S
    pc = cam.transform_points(cam.invert_rigid(c2w.to(positions)), positions)
    z = pc[..., 2]
    front = z > 1e-6
    uv = cam.project_pinhole(
        torch.where(front[..., None], pc, torch.ones_like(pc)), K.to(positions)
    )
    mx, my = margin * width, margin * height
    inside = (
        (uv[..., 0] > -mx)
        & (uv[..., 0] < width + mx)
        & (uv[..., 1] > -my)
        & (uv[..., 1] < height + my)
    )
    return (front & inside & (z < z_min)).any(1)


def train_stage2(
    stage: WorldStage,
    start: int = 0,
    on_step: Optional[Callable[[int, Dict[str, float]], None]] = None,
    progress: bool = True,
) -> None:
    """Run stage-2 iterations start..iterations-1 (see m4dgs.training.stage1.train_loop)."""
    train_loop(
        stage,
        stage.cfg.stage2.iterations,
        start,
        on_step,
        progress,
        "stage 2 (world Gaussians + cameras)",
        ("rgb", "pr"),
    )
