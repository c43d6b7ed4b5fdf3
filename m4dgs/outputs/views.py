"""A trained run seen from the clip's held-out views (benchgen clips: gt/views/<view>/).

The run reconstructs the scene in a world frame of its own (unknown scale and placement), so the
views' cameras, given in the ground truth's frame, are carried into the run's by the similarity
that best maps the run's training-camera centres onto the true ones (Umeyama's least squares,
m4dgs.core.camera.umeyama_sim3, the alignment the camera metrics use):

    c_gt ~ s R c_run + t      a view camera (R_v, c_v) -> (R^T R_v, R^T (c_v - t) / s) in the run

Each view is rendered at its test frame's time with the run's own intrinsics (as its test frames
are), and its depth is reported in the truth's units (x s). A run whose cameras are the truth gets
the identity. Written under renders/views/<view>/ (hdr/<g>.exr, ldr/<level>/<g>.png at every
observed and novel level, depth/<g>.exr) with renders/views/alignment.json (s, R, t, the RMSE of
the aligned training centres in the truth's units, and the number of cameras)."""

from __future__ import annotations

import math
from typing import Dict, Tuple

import torch

from m4dgs.clip import frame_name, level_name
from m4dgs.core.camera import align_to_truth, truth_to_run
from m4dgs.core.io import write_exr, write_json, write_png

__all__ = ["align_to_truth", "truth_to_run", "alignment_of", "render_views"]


def alignment_of(model) -> Dict[str, object]:
    """align_to_truth of a TrainedModel's training cameras against its clip's true cameras."""
    gt = model.clip.load_gt_cameras()
    idx = [list(gt.frames).index(g) for g in model.frames]
    return align_to_truth(model.c2w_train.detach().cpu().double().numpy(), gt.c2w[idx])


@torch.no_grad()
def render_views(model, run, overwrite: bool = False, progress=None) -> Tuple[int, dict]:
    """Render every held-out view of the model's clip into the run folder `run` (a RunDir);
    returns (frames rendered, the alignment). Skips files that exist unless overwrite."""
    clip = model.clip
    views = clip.view_names()
    if not views:
        return 0, {}
    al = alignment_of(model)
    write_json(
        run.path("renders", "views", "alignment.json"),
        {
            "s": al["s"],
            "R": al["R"].tolist(),
            "t": al["t"].tolist(),
            "rmse": al["rmse"],
            "n": al["n"],
            "convention": "c_gt ~ s R c_run + t over the training cameras' centres (Umeyama)",
        },
    )
    levels = list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel)
    K = model.K.detach().cpu().double().numpy()
    done = 0
    jobs = [(v, j, g) for v in views for j, g in enumerate(clip.test_frames)]
    for v, j, g in progress(jobs, desc="render views", unit="frame") if progress else jobs:
        base = run.path("renders", "views", v)
        hdr_p, dep_p = base / "hdr" / frame_name(g, "exr"), base / "depth" / frame_name(g, "exr")
        ldr_ps = {lv: base / "ldr" / level_name(lv) / frame_name(g, "png") for lv in levels}
        if not overwrite and all(p.exists() for p in (hdr_p, dep_p, *ldr_ps.values())):
            continue
        c2w = truth_to_run(clip.load_view_cameras(v).c2w[j], al["s"], al["R"], al["t"])
        r = model.render(model.time_of(g), c2w, K)
        write_exr(hdr_p, r["hdr"].cpu().numpy())
        write_exr(dep_p, (r["depth"] * al["s"]).cpu().numpy())
        for lv, p in ldr_ps.items():
            l2 = torch.tensor(math.log2(lv), dtype=r["hdr"].dtype, device=r["hdr"].device)
            write_png(p, model.tm(r["hdr"], l2).clamp(0, 1).cpu().numpy())
        done += 1
    return done, al
