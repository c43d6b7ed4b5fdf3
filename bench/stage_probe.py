"""Continue stage 2 of a finished run from its final model under several config overrides, each arm
from the same start, and print each arm's loss terms averaged over windows of steps: what a loss
setting does to the fit in a few hundred steps, without training whole runs. A probe for a
mechanism, not a result: the arms start from a model trained under the run's own settings, with
fresh optimiser states.

    python bench/stage_probe.py CLIP RUN --start 8000 --steps 600 --window 100 \\
        --base-overrides "stage2.iterations=11000,stage2.densify_static.stop_iter=8000,..." \\
        --arm "w0.01:stage2.loss.lambda_tlr=0.01" --arm "w0.1:stage2.loss.lambda_tlr=0.1" \\
        --arm "w0.1-floor:stage2.loss.lambda_tlr=0.1,stage2.loss.tlr_den_floor=0.01"

RUN is a finished run folder of CLIP (read only; its models are copied to a temporary folder as
bench/step_bench.py does). --start is the schedule position of the first step (e.g. after the end
of densification, where TLR applies). --base-overrides KEY=VALUE,... apply to every arm (e.g. the
suite row's schedule: pass the run's overrides so that the step's schedule matches the run's).
Each arm seeds torch with --seed before its first step, so the arms draw the same frames as long
as their configurations draw alike.

--from-v2w starts each arm from the run's V2W output (model/v2w.pt: stage 2's own start, its
optimisers fresh as in training) instead of its final model, e.g. to see which loss moves the
Gaussians of a small mover early in stage 2:

    python bench/stage_probe.py CLIP RUN --from-v2w --start 0 --steps 500 --window 100 --emitter \
        --arm "base:" --arm "no-vel:stage2.loss.lambda_vel=0"

--emitter adds, at the end of each window, the distance in pixels from the emitter (the brightest
true-HDR pixel of each training frame, gt/hdr) to the nearest opaque (opacity > 0.3) dynamic
Gaussian, seen by the stage's current cameras (median over the training frames), and how many such
Gaussians lie within 2 px of it (median over the frames): whether the Gaussians that follow a small
bright mover stay on it.

--movers adds, at the end of each window, how much of the true movers' radiance the stage renders:
the median over every fifth training frame with moving pixels (gt/masks/dynamic) of the movers /
still quotient of bench/mover_hdr.py (mean render HDR over the moving pixels / the truth's,
divided by the same over the still pixels; 1 when the movers are as bright, relative to the rest,
as they are), e.g. to see when in stage 2 a small mover's radiance goes:

    python bench/stage_probe.py CLIP RUN --from-v2w --start 0 --steps 2500 --window 250 --movers \
        --arm "base:" --arm "no-reproj:ablation.reproj_loss=false"
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Optional

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
import yaml  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mover_hdr import frame_ratios  # noqa: E402
from step_bench import copy_run_models, make_stage  # noqa: E402
from v2w_lift import pinhole_pixels  # noqa: E402

from m4dgs.clip import Clip  # noqa: E402
from m4dgs.core.threads import use_threads  # noqa: E402
from m4dgs.model.gaussians import WorldGaussians  # noqa: E402
from m4dgs.training.pipeline import Trainer  # noqa: E402
from m4dgs.training.stage2 import CameraRig  # noqa: E402

OPAQUE = 0.3  # "opaque" in the --emitter figures


def parse_overrides(text: str) -> dict:
    """'a.b=1,c.d=true' -> {'a.b': 1, 'c.d': True} (values parsed as YAML scalars)."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise SystemExit(f"override {item!r} is not KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip()] = yaml.safe_load(v)
    return out


def emitters(clip: Clip) -> np.ndarray:
    """[T, 2] pixel centre of the brightest true-HDR pixel (mean of R, G, B) per training frame."""
    out = []
    for g in clip.train_frames:
        hdr = clip.load_gt_hdr(g)[..., :3].mean(-1)
        i = int(np.argmax(hdr))
        out.append((i % hdr.shape[1] + 0.5, i // hdr.shape[1] + 0.5))
    return np.asarray(out, np.float64)


MOVER_STRIDE = 5  # --movers reads every fifth training frame


def mover_truth(clip: Clip, stride: int = MOVER_STRIDE) -> list:
    """[(training index i, true HDR [H, W, 3], moving pixels [H, W] bool)] for every stride-th
    training frame with moving and still pixels (gt/hdr, gt/masks/dynamic): what --movers reads."""
    out = []
    for i, g in list(enumerate(clip.train_frames))[::stride]:
        m = clip.load_gt_dynamic_mask(g)
        if m.any() and not m.all():
            out.append((i, clip.load_gt_hdr(g), m))
    return out


def movers_quotient(stage, truth: list) -> float:
    """The median over `truth` (mover_truth) of bench/mover_hdr.py's movers / still quotient of a
    stage-2 stage's render (WorldStage.render_at at time i from its current camera i); NaN without
    any frame."""
    q = []
    with torch.no_grad():
        cams = stage.cameras()
        for i, hdr, moving in truth:
            r = stage.render_at(float(i), cams[i]).hdr.detach().cpu().numpy()
            a, b = frame_ratios(r, hdr, moving)
            q.append(a / b)
    return float(np.median(q)) if q else float("nan")


def emitter_figures(gaussians: dict, rig: dict, emit: np.ndarray) -> tuple:
    """(median over frames of the distance from the emitter to the nearest opaque dynamic Gaussian,
    median over frames of the number of them within 2 px) for a stage-2 state's "gaussians" and
    "rig" entries (WorldStage.state_dict()) and emitters [T, 2]; (inf, 0) without any."""
    g = WorldGaussians.from_state(gaussians)
    n_static = int(gaussians["static"]["means"].shape[0])
    cam = CameraRig(rig["K"], rig["c2w_init"])
    cam.load_state_dict(rig)
    T = emit.shape[0]
    with torch.no_grad():
        pos = g.positions(torch.arange(T, dtype=torch.float32)).double().numpy()
        opacity = g.opacities().reshape(-1).numpy()
        c2w = cam.c2w().double().numpy()
    pick = (np.arange(opacity.size) >= n_static) & (opacity > OPAQUE)
    if not pick.any():
        return float("inf"), 0.0
    uv = pinhole_pixels(pos[pick], cam.K.double().numpy(), c2w)  # [n, T, 2]
    d = np.linalg.norm(uv - emit[None], axis=-1)
    d = np.where(np.isfinite(d), d, np.inf)
    return float(np.median(d.min(0))), float(np.median((d < 2.0).sum(0)))


def run_arm(
    clip: str,
    src: Path,
    overrides: dict,
    start: int,
    steps: int,
    seed: int,
    preset: str = "small",
    variant: str = "full",
    from_v2w: bool = False,
    window: int = 0,
    emit: Optional[np.ndarray] = None,
    movers: Optional[list] = None,
) -> list:
    """The per-step records of `steps` stage-2 steps from RUN's final model (from_v2w: its V2W
    output) under the preset, the variant and `overrides`. With emitters `emit` [T, 2], the record
    ending each `window` steps also holds "emitter_px" and "emitter_near" (emitter_figures); with
    `movers` (mover_truth), "movers" (movers_quotient) there, and the first record "movers_start",
    the quotient before the first step."""
    tmp = Path(tempfile.mkdtemp(prefix="stage_probe_"))
    try:
        copy_run_models(src, tmp)
        tr = Trainer(clip, tmp, preset, variant, overrides, "cpu", progress=False)
        st, first = make_stage(tr, src, "stage2", start, final=not from_v2w)
        torch.manual_seed(seed)
        recs = []
        start_q = movers_quotient(st, movers) if movers is not None else None
        for k, it in enumerate(range(first, first + steps)):
            rec = st.step(it)
            if k == 0 and start_q is not None:
                rec = {**rec, "movers_start": start_q}
            if window > 0 and (k + 1) % window == 0:
                rec = dict(rec)
                if emit is not None:
                    sd = st.state_dict()
                    rec["emitter_px"], rec["emitter_near"] = emitter_figures(
                        sd["gaussians"], sd["rig"], emit
                    )
                if movers is not None:
                    rec["movers"] = movers_quotient(st, movers)
            recs.append(rec)
        return recs
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip", help="clip folder")
    ap.add_argument("run", help="a finished run folder of the clip (read only)")
    ap.add_argument("--start", type=int, required=True, help="schedule position of the first step")
    ap.add_argument("--steps", type=int, default=400, help="steps per arm")
    ap.add_argument("--window", type=int, default=100, help="steps averaged per printed value")
    ap.add_argument("--preset", default="small", choices=["tiny", "small", "paper"])
    ap.add_argument("--variant", default="full", help="the run's variant")
    ap.add_argument("--base-overrides", default="", help="KEY=VALUE,... for every arm")
    ap.add_argument(
        "--arm",
        action="append",
        required=True,
        help="NAME:KEY=VALUE,... one arm (repeat the option for more arms)",
    )
    ap.add_argument("--terms", default="rgb,tlr,total", help="loss terms to print")
    ap.add_argument(
        "--from-v2w",
        action="store_true",
        help="start each arm from the run's V2W output (model/v2w.pt) instead of its final model",
    )
    ap.add_argument(
        "--emitter",
        action="store_true",
        help="also print, per window, the distance from the brightest true pixel to the nearest "
        "opaque dynamic Gaussian and how many lie within 2 px (needs the clip's gt/hdr)",
    )
    ap.add_argument(
        "--movers",
        action="store_true",
        help="also print, per window, the movers / still quotient of bench/mover_hdr.py over every "
        "fifth training frame (needs the clip's gt/hdr and gt/masks/dynamic)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    a = ap.parse_args()
    use_threads(a.threads, "cpu")
    src = Path(a.run)
    if not (src / "model" / "final.pt").exists():
        ap.error(f"{src} has no model/final.pt: RUN must be a finished run")
    emit = emitters(Clip.open(a.clip)) if a.emitter else None
    truth = mover_truth(Clip.open(a.clip)) if a.movers else None
    base = parse_overrides(a.base_overrides)
    terms = a.terms.split(",")
    print(
        f"steps {a.start}..{a.start + a.steps - 1}, windows of {a.window}; per term: window means"
    )
    for spec in a.arm:
        name, _, ov = spec.partition(":")
        ovr = {**base, **parse_overrides(ov)}
        recs = run_arm(
            a.clip,
            src,
            ovr,
            a.start,
            a.steps,
            a.seed,
            a.preset,
            a.variant,
            from_v2w=a.from_v2w,
            window=a.window,
            emit=emit,
            movers=truth,
        )
        if truth is not None:
            q = [recs[0]["movers_start"]] + [r["movers"] for r in recs if "movers" in r]
            print(
                f"{name:>16s} movers / still (start, then per window): "
                + " ".join(f"{v:.3f}" for v in q)
            )
        if emit is not None:
            ends = [r for r in recs if "emitter_px" in r]
            px = " ".join(f"{r['emitter_px']:.2f}" for r in ends)
            near = " ".join(f"{r['emitter_near']:g}" for r in ends)
            print(f"{name:>16s} emitter px: {px}")
            print(f"{name:>16s} within 2 px: {near}")
        for t in terms:
            vals = []
            for w0 in range(0, len(recs), a.window):
                xs = [r[t] for r in recs[w0 : w0 + a.window] if t in r]
                vals.append(f"{sum(xs) / len(xs):.5f}" if xs else "-")
            print(f"{name:>16s} {t:>6s}: " + " ".join(vals))


if __name__ == "__main__":
    main()
