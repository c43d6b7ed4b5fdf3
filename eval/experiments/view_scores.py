"""Scores at a clip's held-out views (benchgen clips, gt/views/<view>/; docs/clip-format.md).

A prediction at the views is a folder with the views' layout: <root>/<view>/hdr/<g>.exr and
<root>/<view>/ldr/<level>/<g>.png for every test frame g (a run's renders/views, written by
m4dgs.outputs.views; another method's frames under DIR/views/ for `score-frames`). Per view, over
its test frames, at the observed levels (LDR-OE) and the novel ones (LDR-NE) and in HDR:

- PSNR and SSIM over the whole frame (`psnr`, `ssim`);
- the same over the co-visible pixels only (`mpsnr`, `mssim`: the pixels whose surface at least
  two training frames saw, gt/views/<view>/covis; the DyCheck-style masked scores, MSE over the
  mask's pixels, the SSIM map averaged over them);
- HDR with the paper's convention (mu-law on H / max(H_gt)) and the whole-scene one
  (eval.metrics.scene_hdr.hdr_psnr_p99);
- LDR-OE and mu-law HDR PSNR over the co-visible pixels of moving objects (`ldr_oe_dyn_mpsnr`,
  `hdr_dyn_mpsnr`: covis and gt/views/<view>/masks/dynamic; the views' counterpart of the test
  frames' dyn_ldr_psnr / dyn_hdr_psnr). A frame without such a pixel is left out; a view without
  any scores None.

Keys are nv_<view>_<split>_<metric> (split ldr_oe, ldr_ne, hdr; e.g. nv_large_ldr_oe_mpsnr), the
mean over views nv_<split>_<metric>, and nv_<view>_covisible (the mean co-visible fraction of the
view's surface pixels). Every PSNR is capped at PSNR_CAP_DB per frame before the means (as the
test frames' are, eval.experiments.score), so a perfect view reads 100. A prediction may leave out
a whole level or HDR (its folder absent: those scores are None, the split's mean is over the
levels given); a view frame missing from a folder that exists is an error naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from eval.conventions import PSNR_CAP_DB
from eval.metrics.hdr import hdr_psnr, hdr_ssim, hdr_tonemap_pair
from eval.metrics.image import masked_psnr, masked_ssim, psnr, ssim
from eval.metrics.scene_hdr import hdr_psnr_p99
from m4dgs.clip import ClipError, frame_name, level_name
from m4dgs.core import io as mio

SPLITS = ("ldr_oe", "ldr_ne", "hdr")
METRICS = ("psnr", "mpsnr", "ssim", "mssim")
#: the keys over the co-visible moving pixels (module docstring)
DYN_KEYS = ("ldr_oe_dyn_mpsnr", "hdr_dyn_mpsnr")


def _need(p: Path) -> Path:
    if not p.exists():
        raise ClipError(p, "<file>", "missing prediction at a held-out view")
    return p


def _mean(vals: List[Optional[float]]) -> Optional[float]:
    v = [x for x in vals if x is not None and not np.isnan(x)]
    return float(np.mean(v)) if v else None


def _cap(v: Optional[float]) -> Optional[float]:
    """A frame's PSNR capped at PSNR_CAP_DB (identical images give +inf); None stays None."""
    return None if v is None else min(float(v), PSNR_CAP_DB)


def score_view(clip, pred_root, view: str) -> Dict[str, Optional[float]]:
    """{split_metric: value} of one view (module docstring), means over its test frames (and, for
    LDR, over the levels of each split)."""
    root = Path(pred_root) / view
    ex = clip.meta.exposures
    out: Dict[str, List[Optional[float]]] = {f"{s}_{m}": [] for s in SPLITS for m in METRICS}
    out["hdr_psnr_p99"] = []
    out.update({k: [] for k in DYN_KEYS})
    covis_frac = []
    # another method may predict some levels only (a Nerfies-style method: one) and no HDR: a
    # level, or HDR, without a folder is not scored; within a folder every frame is required
    given = [
        lv for lv in list(ex.observed) + list(ex.novel) if (root / "ldr" / level_name(lv)).is_dir()
    ]
    if not given and not (root / "hdr").is_dir():
        raise ClipError(
            root, "<folder>", "no prediction at this held-out view (ldr/<level>/, hdr/)"
        )
    for g in clip.test_frames:
        covis = clip.load_view_covis(view, g)
        hit = clip.load_view_depth(view, g) > 0
        covis_frac.append(float(covis.sum() / max(hit.sum(), 1)))
        # the co-visible moving pixels (masked_psnr gives None where there are none: not scored)
        dyn = covis & clip.load_view_dynamic_mask(view, g)
        for split, levels in (("ldr_oe", ex.observed), ("ldr_ne", ex.novel)):
            for lv in [lv for lv in levels if lv in given]:
                gt = clip.load_view_ldr(view, lv, g)
                pr = mio.read_png(_need(root / "ldr" / level_name(lv) / frame_name(g, "png")))
                out[f"{split}_psnr"].append(_cap(psnr(pr, gt)))
                out[f"{split}_ssim"].append(ssim(pr, gt))
                out[f"{split}_mpsnr"].append(_cap(masked_psnr(pr, gt, covis)))
                out[f"{split}_mssim"].append(masked_ssim(pr, gt, covis))
                if split == "ldr_oe":
                    out["ldr_oe_dyn_mpsnr"].append(_cap(masked_psnr(pr, gt, dyn)))
        if not (root / "hdr").is_dir():
            continue
        gt = clip.load_view_hdr(view, g)
        pr = mio.read_exr(_need(root / "hdr" / frame_name(g, "exr")))
        out["hdr_psnr"].append(_cap(hdr_psnr(pr, gt)))
        out["hdr_ssim"].append(hdr_ssim(pr, gt))
        tp, tg = hdr_tonemap_pair(pr, gt)
        out["hdr_mpsnr"].append(_cap(masked_psnr(tp[0], tg[0], covis)))
        out["hdr_mssim"].append(masked_ssim(tp[0], tg[0], covis))
        out["hdr_dyn_mpsnr"].append(_cap(masked_psnr(tp[0], tg[0], dyn)))
        out["hdr_psnr_p99"].append(_cap(hdr_psnr_p99(pr, gt)))
    res = {k: _mean(v) for k, v in out.items()}
    res["covisible"] = _mean(covis_frac)
    return res


def score_views(clip, pred_root) -> Dict[str, Optional[float]]:
    """Every view of the clip (score_view) as nv_<view>_<key>, and their mean as nv_<key>; {} for
    a clip without views."""
    views = clip.view_names()
    if not views:
        return {}
    per = {v: score_view(clip, pred_root, v) for v in views}
    out: Dict[str, Optional[float]] = {}
    for v, d in per.items():
        out.update({f"nv_{v}_{k}": x for k, x in d.items()})
    for k in next(iter(per.values())):
        out[f"nv_{k}"] = _mean([d[k] for d in per.values()])
    return out
