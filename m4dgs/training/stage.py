"""The training machinery both stages share: exposure set-up, sampling generator, optimisers and the
position learning-rate schedule, the kNN cache, one iteration (`Stage.step`: objective, backward,
optimiser steps, densification through each Gaussian set's strategy) and the loop with its progress
bar (`train_loop`).

A stage (m4dgs.training.stage1.VideoStage, m4dgs.training.stage2.WorldStage) subclasses `Stage` and
supplies its camera model, renderer, Gaussian sets and own loss terms; the objective itself is
m4dgs.training.objective."""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import numpy as np
import torch

from m4dgs.core.errors import NonFiniteError
from m4dgs.core.progress import progress_bar
from m4dgs.model.gaussians import GAIN_KEY
from m4dgs.model.render import RenderResult
from m4dgs.training.config import LossConfig, LRConfig, TrainConfig
from m4dgs.training.data import TrainingData
from m4dgs.training.densify import Strategy
from m4dgs.training.exposure import training_exposures
from m4dgs.training.objective import (
    CameraModel,
    FrameSample,
    KnnCache,
    LossOutput,
    Term,
    Trajectories,
    assemble,
    loss_weights,
    total_loss,
)

# parameters are checked for NaN / inf this often (and before every checkpoint)
PARAMETER_CHECK_EVERY = 25
# per-Gaussian attributes with their own optimiser: video / dynamic sets, static set
SPLINE_KEYS = ("ctrl", "rot", "scales", "opacities", "features")
STATIC_KEYS = ("means", "quats", "scales", "opacities", "features")


def gaussian_keys(params: Mapping[str, torch.nn.Parameter], base: Sequence[str]) -> tuple:
    """The optimised attributes of a Gaussian set: `base` (SPLINE_KEYS / STATIC_KEYS), then the
    log2 gain over time when the set has one (beyond the paper: model.appearance_knots)."""
    return tuple(base) + ((GAIN_KEY,) if GAIN_KEY in params else ())


def check_gain(gauss, cfg: TrainConfig, where: str) -> None:
    """Refuse Gaussians whose gain over time disagrees with model.appearance_knots (a stage-1 or
    V2W result of another configuration)."""
    have, want = gauss.appearance_knots, cfg.model.appearance_knots
    if have != want:
        raise ValueError(
            f"{where}: the Gaussians carry a gain with {have} knots, the configuration asks for "
            f"model.appearance_knots = {want}"
        )


def adam(params, lr: float, eps: float) -> torch.optim.Adam:
    """Adam with torch's fused kernel (one kernel per parameter group instead of a dozen tensor
    operations per step; CPU and CUDA): the same update up to float rounding, 4x faster on the
    small per-attribute optimisers here. `params`: tensors or parameter groups."""
    return torch.optim.Adam(params, lr=lr, eps=eps, fused=True)


def gaussian_optimizers(
    params: Mapping[str, torch.nn.Parameter],
    keys: Sequence[str],
    lr: LRConfig,
    position_scale: float = 1.0,
    dynamic: bool = False,
) -> Dict[str, torch.optim.Optimizer]:
    """One Adam per Gaussian attribute (so densification can edit rows): positions ("ctrl" /
    "means") at lr.position_init x position_scale (the scene extent in world space, 3DGS), the
    others at their LRConfig rates (appendix "Implementation Details"); `dynamic` (the stage-2
    dynamic set): positions and rotations at lr.dynamic_position_init / lr.dynamic_rotation; the
    log2 gain over time (beyond the paper) at lr.gain, or the dynamic set's at lr.dynamic_gain when
    that is set."""
    pos = (lr.dynamic_position_init if dynamic else lr.position_init) * position_scale
    lrs = {
        "ctrl": pos,
        "means": pos,
        "rot": lr.dynamic_rotation if dynamic else lr.rotation,
        "quats": lr.rotation,
        "scales": lr.scale,
        "opacities": lr.opacity,
        "features": lr.features,
        GAIN_KEY: lr.dynamic_gain if dynamic and lr.dynamic_gain is not None else lr.gain,
    }
    return {k: adam([params[k]], lrs[k], lr.adam_eps) for k in keys}


def module_optimizers(
    modules: Mapping[str, torch.nn.Module], lr: LRConfig
) -> Dict[str, torch.optim.Optimizer]:
    """One Adam per module (colour MLP, tone mapper, background) at the MLP rate (paper: 5e-4)."""
    return {name: adam(m.parameters(), lr.mlp, lr.adam_eps) for name, m in modules.items()}


@dataclass
class GaussianSet:
    """One densified set of Gaussians: its parameters, their optimisers, its strategy and state;
    `prefix` names its operation counts in the log ("n_clone", "static_split", ...)."""

    params: Any
    optimizers: Dict[str, torch.optim.Optimizer]
    strategy: Strategy
    state: Dict[str, Any]
    prefix: str
    active: bool = True  # False: never densified (the dynamic set of the static baseline)


class Stage(ABC):
    """Shared state and iteration of a training stage.

    Subclasses set `section` ("stage1" / "stage2": the config section with iterations, lr and loss)
    and implement the hooks below; they hold gauss, color, tm, bg after set-up."""

    section = ""
    extent = 1.0  # length unit of positions (world space: the scene's median depth)
    # render the flow / track target's destination map even when that term is off
    always_render_target = False

    def __init__(self, data: TrainingData, cfg: TrainConfig, device, backend: str, seed: int):
        self.data, self.cfg, self.device, self.backend = data, cfg, torch.device(device), backend
        self.W, self.H = data.width, data.height
        self.c0, self.log2_dt = training_exposures(cfg.exposure, data, self.device)
        self.rng = np.random.default_rng(seed)
        self.knn = KnnCache()

    @property
    def stage_cfg(self):
        return getattr(self.cfg, self.section)

    @property
    def loss_cfg(self) -> LossConfig:
        return self.stage_cfg.loss

    # -- hooks
    # ----------------------------------------------------------------------------------------------
    @property
    def motion(self) -> bool:
        """Whether the Gaussians move (flow / track, TLR and motion regularisers apply)."""
        return True

    def tlr_start_step(self) -> int:
        return self.stage_cfg.tlr_start_step()

    @abstractmethod
    def camera_model(self) -> CameraModel: ...

    @abstractmethod
    def render_view(
        self,
        t: float,
        view: int,
        camera: CameraModel,
        dest_times: Sequence[float] = (),
        detach_camera: bool = False,
    ) -> RenderResult:
        """Render at time t from training view `view` of `camera`."""
        ...

    @abstractmethod
    def trajectories(self) -> Trajectories: ...

    def stage_terms(
        self, it: int, sample: FrameSample, r: RenderResult, camera: CameraModel
    ) -> Iterable[Term]:
        """The stage's own loss terms (added after the shared ones)."""
        return ()

    def stage_weights(self) -> Dict[str, float]:
        return {}

    @abstractmethod
    def gaussian_sets(self) -> List[GaussianSet]: ...

    def split_render_info(self, info: Dict[str, Any]) -> List[Dict[str, Any]]:
        """The render info of each Gaussian set (after backward)."""
        return [info]

    @abstractmethod
    def all_optimizers(self) -> List[torch.optim.Optimizer]: ...

    @abstractmethod
    def position_optimizers(self) -> List[torch.optim.Optimizer]: ...

    def position_lrs(self, it: int) -> List[Tuple[torch.optim.Optimizer, float]]:
        """(optimizer, learning rate) of each position optimizer at step `it`: the stage's 3DGS
        decay (LRConfig.position_lr) x the scene extent, for all of them unless a stage overrides
        it (stage 2: the dynamic Gaussians' own rates)."""
        sc = self.stage_cfg
        lr = sc.lr.position_lr(it, sc.iterations) * self.extent
        return [(o, lr) for o in self.position_optimizers()]

    def after_step(self, it: int) -> Dict[str, int]:
        """Stage-specific edits after densification (counts for the log)."""
        return {}

    def record(self) -> Dict[str, Any]:
        return {"num_gaussians": self.gauss.num_gaussians}

    # -- one iteration
    # ----------------------------------------------------------------------------------------------
    def losses(self, it: int) -> LossOutput:
        """This iteration's loss terms and the query render's metadata
        (m4dgs.training.objective.assemble)."""
        return assemble(self, it)

    def weights(self) -> Dict[str, float]:
        return loss_weights(self.loss_cfg, self.cfg.tonemap, self.stage_weights())

    def step(self, it: int) -> Dict[str, float]:
        optimizers = self.all_optimizers()
        for o in optimizers:
            o.zero_grad(set_to_none=True)
        for o, lr in self.position_lrs(it):
            for group in o.param_groups:
                group["lr"] = lr
        try:
            L, meta = self.losses(it)
        except NonFiniteError as e:  # raised inside a loss (e.g. the tone mapper): add where
            raise NonFiniteError(
                f"{self.section}: step {it}: {e}; training stopped, the last checkpoint is kept. "
                "HDR values beyond float32's range come from colours that grow without bound "
                "(docs/reliability.md, non-finite values)"
            ) from e
        total = total_loss(L, self.weights())
        info = {"means2d": meta.means2d, "radii": meta.radii, "width": self.W, "height": self.H}
        sets = self.gaussian_sets()
        for s in sets:
            s.strategy.step_pre_backward(s.params, s.optimizers, s.state, it, info)
        total.backward()
        # every logged value in one read from the device (each read waits for it on CUDA), taken
        # after backward so that the backward kernels are queued before the wait; a non-finite
        # loss stops the step before any parameter moves
        values = torch.stack(
            [total.detach().double().reshape(())]
            + [v.detach().double().reshape(()) for v in L.values()]
        ).tolist()
        total_value = values[0]
        if not math.isfinite(total_value):
            self.raise_non_finite(it, L)
        for o in optimizers:
            o.step()
        counts = self.densify(it, info, sets)
        if counts:
            self.knn.invalidate()
        counts.update(self.after_step(it))
        if (it + 1) % PARAMETER_CHECK_EVERY == 0 or (it + 1) % self.cfg.checkpoint_every == 0:
            self.check_parameters(it)
        rec = dict(zip(L.keys(), values[1:]))
        rec["total"] = total_value
        rec.update(self.record())
        rec.update(counts)
        return rec

    def raise_non_finite(self, it: int, terms: Mapping[str, torch.Tensor]) -> None:
        """Stop at a non-finite loss, naming the stage, the step and the terms that are not finite
        (the run's last checkpoint is from before this step and stays as it is)."""
        bad = [f"{k}={float(v.detach())}" for k, v in terms.items() if not torch.isfinite(v).all()]
        what = ", ".join(bad) if bad else "the weighted sum (a weight is not finite)"
        raise NonFiniteError(
            f"{self.section}: step {it}: non-finite loss ({what}); training stopped, the last "
            "checkpoint is kept. Check the clip's inputs and the loss settings (--set)"
        )

    def check_parameters(self, it: int) -> None:
        """Stop when a parameter (Gaussians, MLPs, cameras) holds NaN or infinite values; runs
        before a checkpoint could store them and every PARAMETER_CHECK_EVERY steps."""
        for o in self.all_optimizers():
            for group in o.param_groups:
                for p in group["params"]:
                    if not bool(torch.isfinite(p.detach()).all()):
                        name = next(
                            (k for k, q in self.named_parameters() if q is p), f"{tuple(p.shape)}"
                        )
                        raise NonFiniteError(
                            f"{self.section}: step {it}: parameter {name} holds NaN or infinite "
                            "values; training stopped, the last checkpoint is kept"
                        )

    def named_parameters(self) -> Iterable[Tuple[str, torch.Tensor]]:
        """(name, tensor) of the Gaussian sets' and the modules' parameters, for error messages."""
        for s in self.gaussian_sets():
            for k, v in s.params.items():
                yield f"{s.prefix}{k}", v
        for name in ("color", "tm", "bg", "rig"):  # colour MLP, tone mapper, background, cameras
            module = getattr(self, name, None)
            if isinstance(module, torch.nn.Module):
                for k, v in module.named_parameters():
                    yield f"{name}.{k}", v

    def densify(self, it: int, info: Dict[str, Any], sets: List[GaussianSet]) -> Dict[str, int]:
        """Each active set's strategy after backward (statistics; clone / split / prune / reset on
        schedule); nothing when no gradient reached the projected means. Returns the non-zero
        operation counts."""
        counts: Dict[str, int] = {}
        if info["means2d"].grad is None:
            return counts
        for s, inf in zip(sets, self.split_render_info(info)):
            if not s.active:
                continue
            c = s.strategy.step_post_backward(s.params, s.optimizers, s.state, it, inf)
            counts.update({f"{s.prefix}{k}": v for k, v in c.items() if v})
        return counts


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
    and a callback after each step (logging, checkpoints). Shared by both stages. The bar starts
    after the first step: that step's one-time costs (the kernels' first calls, caches) would
    otherwise set its rate and ETA for a long while."""
    bar = None
    for it in range(start, iterations):
        t0 = time.perf_counter()
        rec = stage.step(it)
        rec["sec"] = time.perf_counter() - t0
        if on_step is not None:
            on_step(it, rec)
        if progress and bar is None:
            bar = progress_bar(total=iterations, initial=it + 1, desc=desc, unit="it")
        elif bar is not None:
            bar.update(1)
        if bar is not None:
            if it % 10 == 0 or it == iterations - 1 or it == start:
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
