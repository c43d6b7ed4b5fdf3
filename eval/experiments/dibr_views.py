"""The `dibr` calibration row at the held-out views: the nearest training frame forward-warped into
each view (eval.calibration.predict.dibr) with what a method has, not the truth:

- the response estimated from the training frames (eval.calibration.predict.response_of);
- the depth prior of that frame in the world units of the method's own camera initialisation
  (the trainer's camera_init phase, run here in a work folder: bundle adjustment of the training
  cameras and a scale per frame for the depth prior);
- the views' true cameras carried into that camera initialisation's frame exactly as a trained
  run's are (m4dgs.outputs.views: the similarity fitted on the training cameras), seen with its
  intrinsics.

Writes <out>/<view>/hdr/<g>.exr and <out>/<view>/ldr/<level>/<g>.png for every test frame g, the
layout eval.experiments.view_scores reads."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from eval.calibration.frames import response_record
from eval.calibration.predict import ClipFrames, dibr, ldr_at, response_of
from eval.calibration.response import radiance
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.outputs.views import align_to_truth, truth_to_run
from m4dgs.run import load_torch


def camera_initialisation(
    clip_dir, work, preset: str = "small", overrides=None, share_dir=None
) -> dict:
    """The trainer's camera initialisation of a clip (m4dgs.training.pipeline.Trainer, variant
    full at `preset`), run in the folder `work`: {"K" [3, 3], "c2w" [T, 4, 4], "depth" [T, H, W]
    (the depth priors times their per-frame scale: world units)}; `overrides`: config overrides by
    dotted key, as `m4dgs train --set`; `share_dir`: the suite's share folder (OUT/.shared), where
    the phase is taken from a run of the same clip, configuration and seed that computed it."""
    from m4dgs.training.pipeline import Trainer

    trainer = Trainer(
        clip_dir, work, preset, "full", overrides, progress=False, share_dir=share_dir
    )
    trainer.run_phase("camera_init")
    ci = load_torch(Path(work) / "model" / "camera_init.pt")
    depth = (
        trainer.data.depth.cpu().double().numpy()
        * ci["depth_scale"].double().numpy()[:, None, None]
    )
    return {"K": ci["K"].double().numpy(), "c2w": ci["c2w"].double().numpy(), "depth": depth}


def write_dibr_views(
    clip_dir,
    out,
    preset: str = "small",
    work=None,
    overrides=None,
    share_dir=None,
    response_json=None,
) -> Path:
    """Write the dibr row's predictions at every held-out view of the clip into `out` (module
    docstring); `work`: the folder for the camera initialisation (default a temporary one),
    `overrides` and `share_dir`: as camera_initialisation's; `response_json`: where to write the
    estimated response (eval.calibration.frames's response.json), if given."""
    clip = Clip.open(clip_dir)
    out = Path(out)
    views = clip.view_names()
    if not views:
        raise ValueError(f"{clip.root}: the clip has no held-out views (gt/views/)")
    cf = ClipFrames.of(clip)
    g_resp = response_of(cf)
    if response_json is not None:
        mio.write_json(response_json, response_record("dibr", g_resp))
    with tempfile.TemporaryDirectory() as tmp:
        ci = camera_initialisation(
            clip_dir, work or Path(tmp) / "run", preset, overrides, share_dir
        )
    gt = clip.load_gt_cameras()
    idx = [list(gt.frames).index(g) for g in cf.frames]
    al = align_to_truth(ci["c2w"], gt.c2w[idx])
    levels = list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel)
    t = np.asarray(cf.frames, np.float64)
    for v in views:
        cams = clip.load_view_cameras(v)
        for j, g in enumerate(clip.test_frames):
            i = int(np.argmin(np.abs(t - g) + 1e-9 * (t > g)))
            hdr, _ = dibr(
                radiance(cf.ldr[i], cf.dt[i], g_resp),
                ci["depth"][i],
                ci["K"],
                ci["c2w"][i],
                ci["K"],
                truth_to_run(cams.c2w[j], al["s"], al["R"], al["t"]),
                clip.width,
                clip.height,
            )
            hdr = hdr.astype(np.float32)
            mio.write_exr(out / v / "hdr" / frame_name(g, "exr"), hdr)
            for lv in levels:
                mio.write_png(
                    out / v / "ldr" / level_name(lv) / frame_name(g, "png"),
                    ldr_at(hdr, float(lv), g_resp),
                )
    return out
