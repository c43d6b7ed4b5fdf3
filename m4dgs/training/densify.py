"""Adaptive density control of Gaussians (3DGS-style clone / split / prune / opacity reset) as a
strategy object.

Paper: "We follow the same densification strategy as 3DGS for all Gaussians at both stages"
(appendix), stage 1 densifies for 3K iterations every 200 steps and resets opacities every 1K steps;
stage 2 densifies for 8K iterations, static Gaussians every 400 steps, dynamic ones every 200 steps,
opacity resets every 2K (sec. "Implementation Details"). Thresholds from the authors' code: gradient
threshold 2e-4 (their code raises it by a quantile schedule; here an option), clone/split boundary
on the largest scale 0.01 (video-space units in stage 1), split into 2 with scales / 1.6, prune
opacity < 0.005, reset opacity to 0.01, at most 150k Gaussians.

The strategy works on any dict of per-Gaussian parameters whose first dimension is N (any trailing
shape: spline control points [N, K, 3], rotation polynomial coefficients [N, J, 4], features [N, C],
opacity logits [N] ...), and keeps the Adam state (exp_avg, exp_avg_sq) row-aligned with the
parameters: new rows get zero moments, removed rows are dropped. A `GaussianLayout`
(m4dgs.model.layout) says which keys hold positions (offset when splitting), scales and opacities
and how they are activated. Stage 2 uses one strategy per Gaussian set (static and dynamic), each
with its own config.

Typical loop (gsplat-like):

    strategy = Strategy(cfg, layout); state = strategy.initialize_state() info = render(...)
    # info["means2d"] [N, 2] in pixels, info["radii"] strategy.step_pre_backward(params, optimizers,
    state, step, info) loss.backward() strategy.step_post_backward(params, optimizers, state, step,
    info)   # info also needs "width", "height" optimizer.step()
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterable, Mapping, MutableMapping, Optional, Union

import torch
from torch import nn

from m4dgs.core.camera import quat_to_rotmat
from m4dgs.model.layout import GaussianLayout

Tensor = torch.Tensor
Optimizers = Union[
    torch.optim.Optimizer, Mapping[str, torch.optim.Optimizer], Iterable[torch.optim.Optimizer]
]


@dataclass
class DensifyConfig:
    """Densification schedule and thresholds (appendix "Gaussian Densification", "Implementation
    Details")."""

    # 3DGS: mean 2D positional gradient (NDC units) above which a Gaussian grows
    grad_threshold: float = 2e-4
    grad_quantile: Optional[float] = (
        None  # authors' code: threshold = max(grad_threshold, quantile(grads, q)); None = off
    )
    # largest scale <= this x the strategy's extent: clone, else split (3DGS: percent_dense 0.01
    # x scene extent; the authors' code: an absolute 0.01). The extent is the Strategy's `extent`
    # (stage 1: 1, video space; stage 2: Stage2Config.clone_split_extent)
    clone_split_scale: float = 0.01
    split_count: int = 2  # split one Gaussian into this many samples (3DGS: 2)
    split_scale_factor: float = 1.6  # split samples get scales / 1.6 (3DGS)
    prune_opacity: float = 0.005  # prune Gaussians with opacity below this (3DGS)
    reset_opacity_value: float = 0.01  # opacity reset clamps opacities to at most this value (3DGS)
    max_gaussians: int = 150_000  # growth cap (authors' code)
    start_iter: int = 500  # densify only after this step (3DGS default)
    stop_iter: int = 3_000  # stage 1: 3K densification iterations (paper)
    every: int = 200  # stage 1: densify every 200 steps (paper)
    reset_every: int = 1_000  # stage 1: opacity reset every 1K steps (paper)
    # skip densification this many steps after a reset (gsplat option; 0 = 3DGS)
    pause_after_reset: int = 0
    # 3DGS prunes largest scale > 0.1 x scene extent; None = off (bounded scales)
    prune_scale: Optional[float] = None
    # 3DGS prunes screen radius > 20 px after the first reset; None = off
    prune_radius2d: Optional[float] = None


# --------------------------------------------------------------------------------------------------
# parameter / optimizer surgery
# --------------------------------------------------------------------------------------------------
def _optimizer_list(optimizers: Optimizers) -> list:
    if optimizers is None:
        return []
    if isinstance(optimizers, torch.optim.Optimizer):
        return [optimizers]
    if isinstance(optimizers, Mapping):
        return list(optimizers.values())
    return list(optimizers)


def update_params_and_optimizers(
    params: MutableMapping[str, Tensor],
    optimizers: Optimizers,
    param_fn: Callable[[str, Tensor], Tensor],
    state_fn: Callable[[str, str, Tensor], Tensor],
    names: Optional[Iterable[str]] = None,
) -> None:
    """Replace each parameter by `param_fn(name, old)` and its optimizer state rows by
    `state_fn(name, key, old)`.

    The new nn.Parameter takes the old one's place in `params` and in every optimizer param group
    that held it; the optimizer's per-parameter state (tensors whose first dimension is N, e.g.
    Adam's exp_avg / exp_avg_sq) is mapped by state_fn, scalar entries (Adam's "step") are kept."""
    opts = _optimizer_list(optimizers)
    for name in list(names) if names is not None else list(params.keys()):
        old = params[name]
        new_data = param_fn(name, old.detach())
        new = nn.Parameter(new_data, requires_grad=old.requires_grad)
        n_old = old.shape[0]
        for opt in opts:
            for group in opt.param_groups:
                for i, q in enumerate(group["params"]):
                    if q is old:
                        group["params"][i] = new
                        st = opt.state.pop(old, None)
                        if st is not None:
                            for key, val in list(st.items()):
                                if torch.is_tensor(val) and val.dim() > 0 and val.shape[0] == n_old:
                                    st[key] = state_fn(name, key, val)
                            opt.state[new] = st
        params[name] = new


def _zeros_rows(v: Tensor, n: int) -> Tensor:
    return torch.zeros((n, *v.shape[1:]), dtype=v.dtype, device=v.device)


def duplicate_gaussians(params, optimizers, mask: Tensor) -> None:
    """Append a copy of every Gaussian in `mask` [N] bool (new optimizer rows are zero)."""
    sel = torch.where(mask)[0]
    update_params_and_optimizers(
        params,
        optimizers,
        lambda name, p: torch.cat([p, p[sel]]),
        lambda name, key, v: torch.cat([v, _zeros_rows(v, sel.numel())]),
    )


def remove_gaussians(params, optimizers, mask: Tensor) -> None:
    """Drop every Gaussian in `mask` [N] bool, with its optimizer rows."""
    keep = torch.where(~mask)[0]
    update_params_and_optimizers(
        params, optimizers, lambda name, p: p[keep], lambda name, key, v: v[keep]
    )


def split_gaussians(
    params,
    optimizers,
    mask: Tensor,
    layout: GaussianLayout,
    *,
    count: int = 2,
    scale_factor: float = 1.6,
    generator: Optional[torch.Generator] = None,
) -> None:
    """Replace each Gaussian in `mask` by `count` samples drawn from it (3DGS split).

    Sample positions: mu + R (s * eps), eps ~ N(0, I), with R, s the Gaussian's rotation and scales;
    for trajectory parameters (control points) the same offset moves every control point. The
    samples' scales are s / scale_factor; all other attributes are copied. The split Gaussians are
    removed; the samples are appended (zero optimizer rows)."""
    sel = torch.where(mask)[0]
    rest = torch.where(~mask)[0]
    m = sel.numel()
    scales = layout.scale_fn(params[layout.scale_key].detach()[sel])  # [M, 3]
    rots = quat_to_rotmat(layout.rotations(params).detach()[sel]).to(scales.dtype)  # [M, 3, 3]
    eps = torch.randn((count, m, 3), dtype=scales.dtype, device=scales.device, generator=generator)
    # sample-major
    offsets = torch.einsum("mij,cmj->cmi", rots, scales[None] * eps).reshape(count * m, 3)

    def param_fn(name: str, p: Tensor) -> Tensor:
        src = p[sel]
        rep = src.repeat(count, *([1] * (p.dim() - 1)))  # [count * M, ...] sample-major
        if name in layout.position_keys:
            rep = rep + offsets.to(p.dtype).view(count * m, *([1] * (p.dim() - 2)), 3)
        elif name == layout.scale_key:
            rep = layout.scale_inv_fn(layout.scale_fn(rep) / scale_factor).to(p.dtype)
        return torch.cat([p[rest], rep])

    update_params_and_optimizers(
        params,
        optimizers,
        param_fn,
        lambda name, key, v: torch.cat([v[rest], _zeros_rows(v, count * m)]),
    )


def reset_opacity(params, optimizers, opacity_key: str, value: float) -> None:
    """Clamp opacities to at most `value` (3DGS opacity reset); the opacity optimizer state is
    zeroed."""
    logit = math.log(value / (1.0 - value))
    update_params_and_optimizers(
        params,
        optimizers,
        lambda name, p: torch.clamp(p, max=logit),
        lambda name, key, v: torch.zeros_like(v),
        names=[opacity_key],
    )


# --------------------------------------------------------------------------------------------------
# strategy
# --------------------------------------------------------------------------------------------------
class Strategy:
    """3DGS adaptive density control for one set of Gaussians (see module docstring).

    State (`initialize_state()`): "grad2d" [N] accumulated 2D gradient norms, "count" [N] visibility
    counts, "radii" [N] largest screen radius seen (pixels), "born" [N] the step at which each
    Gaussian was created by a clone or split (-1: initial set); created lazily at the first
    update."""

    def __init__(
        self,
        cfg: Optional[DensifyConfig] = None,
        layout: Optional[GaussianLayout] = None,
        seed: int = 0,
        extent: float = 1.0,
    ):
        self.cfg = cfg or DensifyConfig()
        self.layout = layout or GaussianLayout()
        self.seed = seed
        # scene extent the clone/split boundary scales with (3DGS: percent_dense x extent)
        self.extent = float(extent)
        self._generators: Dict[torch.device, torch.Generator] = {}

    def _generator(self, device: torch.device) -> torch.Generator:
        dev = torch.device(device)
        if dev not in self._generators:
            g = torch.Generator(device=dev)
            g.manual_seed(self.seed)
            self._generators[dev] = g
        return self._generators[dev]

    def state_dict(self) -> Dict[str, Any]:
        """The random generators' states (split samples), for checkpoints: a resumed run draws the
        same splits as an uninterrupted one."""
        return {"generators": {str(d): g.get_state() for d, g in self._generators.items()}}

    def load_state_dict(self, sd: Dict[str, Any]) -> None:
        for dev, state in sd.get("generators", {}).items():
            # a generator's state is a CPU byte tensor whatever its device; `torch.load(...,
            # map_location="cuda")` moves it to the GPU, where `set_state` refuses it
            self._generator(torch.device(dev)).set_state(
                torch.as_tensor(state).to("cpu", torch.uint8)
            )

    @staticmethod
    def initialize_state() -> Dict[str, Any]:
        return {
            "grad2d": None,
            "count": None,
            "radii": None,
            "born": None,
            "last_reset": -(10**9),
        }

    @staticmethod
    def born(state: Mapping[str, Any], n: int, device=None) -> Tensor:
        """[n] creation steps of the Gaussians ("born" state; -1 = initial set, also for a state
        without the record, e.g. an older checkpoint's)."""
        b = state.get("born")
        if b is None or b.shape[0] != n:
            return torch.full((n,), -1, dtype=torch.long, device=device)
        return b

    def check_sanity(self, params: Mapping[str, Tensor]) -> None:
        """Raise ValueError if the layout's keys are missing or the first dimensions disagree."""
        lay = self.layout
        needed = [*lay.position_keys, lay.scale_key, lay.opacity_key]
        if lay.rotation_fn is None:
            needed.append(lay.rotation_key)
        missing = [k for k in needed if k not in params]
        if missing:
            raise ValueError(
                f"densification: parameter dict lacks {missing} (has {sorted(params)})"
            )
        sizes = {k: v.shape[0] for k, v in params.items()}
        if len(set(sizes.values())) > 1:
            raise ValueError(
                f"densification: parameters disagree on the number of Gaussians: {sizes}"
            )

    # --- hooks
    # ----------------------------------------------------------------------------------------------
    def step_pre_backward(
        self, params, optimizers, state, step: int, info: Mapping[str, Any]
    ) -> None:
        """Ask autograd to keep the gradient of the projected means (info["means2d"])."""
        means2d = info.get("means2d")
        if means2d is not None and means2d.requires_grad and not means2d.is_leaf:
            means2d.retain_grad()

    def step_post_backward(
        self, params, optimizers, state, step: int, info: Mapping[str, Any]
    ) -> Dict[str, int]:
        """Accumulate statistics and, on schedule, clone / split / prune and reset opacities.

        Args:
            info: "means2d" (tensor whose .grad holds d loss / d pixel position, [N, 2] or [C, N,
            2]) or
                "means2d_grad" (that gradient directly), "radii" ([N], [N, 2] or with a leading C),
                "width", "height".
        Returns:
            counts of this step's operations: {"clone", "split", "prune", "reset"} (zeros when
            nothing happened).
        """
        cfg = self.cfg
        out = {"clone": 0, "split": 0, "prune": 0, "reset": 0}
        if step >= cfg.stop_iter or next(iter(params.values())).shape[0] == 0:
            return out  # an empty set (e.g. no dynamic Gaussian after V2W): nothing to densify
        self._update_state(params, state, info)
        if (
            step > cfg.start_iter
            and step % cfg.every == 0
            and step - state.get("last_reset", -(10**9)) >= cfg.pause_after_reset
        ):
            n_clone, n_split = self.grow(params, optimizers, state, step)
            n_prune = self.prune(params, optimizers, state, step)
            out.update(clone=n_clone, split=n_split, prune=n_prune)
            n = next(iter(params.values())).shape[0]
            dev = next(iter(params.values())).device
            state["grad2d"] = torch.zeros(n, device=dev)
            state["count"] = torch.zeros(n, device=dev)
            state["radii"] = torch.zeros(n, device=dev)
        if step > 0 and step % cfg.reset_every == 0:
            reset_opacity(params, optimizers, self.layout.opacity_key, cfg.reset_opacity_value)
            state["last_reset"] = step
            out["reset"] = 1
        return out

    # --- internals
    # ----------------------------------------------------------------------------------------------
    def _update_state(self, params, state, info) -> None:
        grads = info.get("means2d_grad")
        if grads is None:
            means2d = info["means2d"]
            grads = means2d.grad
            if grads is None:
                raise ValueError(
                    "densification: info['means2d'] has no gradient; call step_pre_backward "
                    "before backward"
                )
        if "width" not in info or "height" not in info:
            raise ValueError(
                "densification: info needs 'width' and 'height' (image size in pixels)"
            )
        width, height = float(info["width"]), float(info["height"])
        grads = grads.detach()
        n = grads.shape[-2]
        n_params = next(iter(params.values())).shape[0]
        if n != n_params:
            raise ValueError(
                f"densification: means2d gradient covers {n} Gaussians, the parameters hold "
                f"{n_params}"
            )
        if info["radii"].numel() not in (grads.numel(), grads.numel() // 2):
            raise ValueError(
                f"densification: radii shape {tuple(info['radii'].shape)} does not match {n} "
                "Gaussians"
            )
        grads = grads.reshape(-1, n, 2)
        # pixel-space gradient -> NDC units of 3DGS (the threshold 2e-4 is in those units), as
        # gsplat does
        scale = (
            torch.tensor([width / 2.0, height / 2.0], dtype=grads.dtype, device=grads.device)
            * grads.shape[0]
        )
        norms = (grads * scale).norm(dim=-1)  # [C, N]
        radii = info["radii"].detach()
        if radii.numel() == grads.numel():  # per-axis radii [..., N, 2] (gsplat >= 1.5)
            radii = radii.reshape(-1, n, 2)
            vis = (radii > 0).all(dim=-1)
            rmax = radii.max(dim=-1).values
        else:
            radii = radii.reshape(-1, n)
            vis = radii > 0
            rmax = radii
        dev = grads.device
        if state.get("grad2d") is None:
            self.check_sanity(params)
        if state.get("grad2d") is None or state["grad2d"].shape[0] != n:
            state["grad2d"] = torch.zeros(n, device=dev)
            state["count"] = torch.zeros(n, device=dev)
            state["radii"] = torch.zeros(n, device=dev)
        state["grad2d"] += (norms * vis).sum(0).float()
        state["count"] += vis.sum(0).float()
        state["radii"] = torch.maximum(state["radii"], (rmax.float() * vis).max(0).values)
        state["born"] = self.born(state, n, dev)

    def grow(self, params, optimizers, state, step: int) -> tuple[int, int]:
        """Clone small and split large Gaussians whose mean 2D gradient exceeds the threshold
        (respecting the cap)."""
        cfg, lay = self.cfg, self.layout
        count = state["count"]
        avg = state["grad2d"] / count.clamp_min(1.0)
        thr = cfg.grad_threshold
        if cfg.grad_quantile is not None and (count > 0).any():
            thr = max(thr, float(torch.quantile(avg[count > 0], cfg.grad_quantile)))
        high = (avg > thr) & (count > 0)
        max_scale = lay.scale_fn(params[lay.scale_key].detach()).max(dim=-1).values
        n = max_scale.shape[0]
        is_small = max_scale <= cfg.clone_split_scale * self.extent
        budget = cfg.max_gaussians - n
        if budget <= 0:
            return 0, 0
        cand = torch.where(high)[0]
        cost = torch.where(is_small[cand], 1, cfg.split_count - 1)
        if int(cost.sum()) > budget:
            order = torch.argsort(avg[cand], descending=True)
            cand = cand[order]
            keep = torch.cumsum(cost[order], 0) <= budget
            cand = cand[keep]
        chosen = torch.zeros(n, dtype=torch.bool, device=high.device)
        chosen[cand] = True
        clone_mask = chosen & is_small
        split_mask = chosen & ~is_small
        n_clone, n_split = int(clone_mask.sum()), int(split_mask.sum())
        state["born"] = self.born(state, n, high.device)
        if n_clone:
            duplicate_gaussians(params, optimizers, clone_mask)
            for key in ("grad2d", "count", "radii"):
                state[key] = torch.cat([state[key], state[key][clone_mask]])
            state["born"] = torch.cat([state["born"], state["born"].new_full((n_clone,), step)])
            split_mask = torch.cat(
                [split_mask, torch.zeros(n_clone, dtype=torch.bool, device=split_mask.device)]
            )
        if n_split:
            dev = params[lay.scale_key].device
            split_gaussians(
                params,
                optimizers,
                split_mask,
                lay,
                count=cfg.split_count,
                scale_factor=cfg.split_scale_factor,
                generator=self._generator(dev),
            )
            for key in ("grad2d", "count", "radii"):
                v = state[key]
                state[key] = torch.cat([v[~split_mask], v[split_mask].repeat(cfg.split_count)])
            b = state["born"]
            state["born"] = torch.cat(
                [b[~split_mask], b.new_full((n_split * cfg.split_count,), step)]
            )
        return n_clone, n_split

    def remove(self, params, optimizers, state, mask: Tensor) -> int:
        """Remove the Gaussians in `mask` [N] bool, keeping parameters, optimizer rows and
        statistics aligned (e.g. the stage-2 removal of mistakenly densified dynamic Gaussians)."""
        n_remove = int(mask.sum())
        if n_remove:
            remove_gaussians(params, optimizers, mask)
            for key in ("grad2d", "count", "radii", "born"):
                if state.get(key) is not None and state[key].shape[0] == mask.shape[0]:
                    state[key] = state[key][~mask.to(state[key].device)]
        return n_remove

    def prune(self, params, optimizers, state, step: int) -> int:
        """Remove transparent Gaussians (and, when enabled, too large ones)."""
        cfg, lay = self.cfg, self.layout
        opac = torch.sigmoid(params[lay.opacity_key].detach()).reshape(
            params[lay.opacity_key].shape[0], -1
        )[:, 0]
        mask = opac < cfg.prune_opacity
        if step > cfg.reset_every:
            if cfg.prune_scale is not None:
                mask |= (
                    lay.scale_fn(params[lay.scale_key].detach()).max(dim=-1).values
                    > cfg.prune_scale
                )
            if cfg.prune_radius2d is not None and state.get("radii") is not None:
                mask |= state["radii"] > cfg.prune_radius2d
        return self.remove(params, optimizers, state, mask)
