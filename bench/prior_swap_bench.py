"""Which degraded prior breaks the camera initialisation? Swaps prior families between two clips
of one render and runs the trainer's camera-initialisation phase on each combination.

    python bench/prior_swap_bench.py --base ROOT/clips/syn-exp-3 \\
        --other ROOT/clips/syn-exp-3-priors-harsh --scenes lamp-room-orbit,robot-arm-dolly \\
        --out OUT [--preset small] [--combos single|all|depth|...] [--json OUT.json]

`--base` and `--other` are suite folders holding a clip per scene made from the same render
(clip.json gt.render_key, checked) with different priors, e.g. a realistic and a harsh
profile (`benchgen make --priors`). For every scene and every combination of the three prior
families (depth, tracks, flow) taken from `--other` (`single`: none, each family alone, all three;
`all`: the eight subsets), the script assembles a clip under OUT/clips/SCENE/COMBO whose input and
ground truth are links to the base clip's and whose priors are links to the chosen clips' priors,
then runs `Trainer.run_phase("camera_init")` of the given preset into OUT/runs/SCENE/COMBO: exactly
the phase `m4dgs train` runs (dynamic masks, bundle adjustment, the mask refinement and second
bundle adjustment of the small preset), seeded as the trainer seeds it. Scores against the clip's
ground truth: focal error (%), ATE after Sim(3) alignment (GT units), RPE (translation, rotation
in degrees per frame; eval.metrics.geometry) and the IoU of the dynamic masks against
gt/masks/dynamic, pooled over the training frames.

Resumable: a combination whose run has model/camera_init.pt is scored, not recomputed. One camera
initialisation costs about 40 s at the small preset on an idle 2-core machine."""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

FAMILIES = ("depth", "tracks", "flow")
PRIOR_FILES = {"depth": "depth", "tracks": "tracks.npz", "flow": "flow.npz"}


def combinations(kind: str) -> List[Tuple[str, ...]]:
    """The families taken from the other clip, per combination: `single` = (), each family alone
    and all three; `all` = the eight subsets (in order of size); FAMILY[+FAMILY...] (e.g.
    `depth` or `depth+flow`) = () and that set."""
    if kind == "single":
        return [()] + [(f,) for f in FAMILIES] + [FAMILIES]
    if kind == "all":
        return [c for n in range(4) for c in itertools.combinations(FAMILIES, n)]
    fams = tuple(f for f in FAMILIES if f in kind.split("+"))
    if fams and len(fams) == len(kind.split("+")):
        return [(), fams]
    raise ValueError(f"--combos {kind!r}: one of single, all, or families joined by + {FAMILIES}")


def combo_name(families: Sequence[str], other: str = "other") -> str:
    """Folder name of a combination: 'base', 'other' (all three) or e.g. 'other-depth+flow'
    (`other` names the other clips, so that several of them can share one --out and its base
    runs)."""
    if not families:
        return "base"
    if tuple(families) == FAMILIES:
        return other
    return f"{other}-" + "+".join(families)


def same_render(base: Path, other: Path) -> bool:
    """True when two clips come from one render (clip.json gt.render_key, benchgen's fingerprint
    of everything the render reads) and train on the same frames: their priors were computed from
    the same ground truth. Their 8-bit inputs may still differ by one code in a few pixels when
    one was made before benchgen reused the HDR scale with the render (docs/rendering.md)."""
    a, b = (json.loads((Path(c) / "clip.json").read_text()) for c in (base, other))
    key_a, key_b = a.get("gt", {}).get("render_key"), b.get("gt", {}).get("render_key")
    return key_a is not None and key_a == key_b and a.get("split") == b.get("split")


def assemble_clip(base: Path, other: Path, families: Sequence[str], out: Path) -> Path:
    """Clip folder `out` with base's clip.json, input/ and gt/ and, for each family in `families`,
    other's prior (the rest base's). Links, no copies; clip.json's `priors` entry says where each
    family came from. Raises ValueError naming both folders when the two clips do not share
    their input frames."""
    base, other, out = Path(base), Path(other), Path(out)
    for c in (base, other):
        if not (c / "clip.json").is_file():
            raise ValueError(f"{c}: not a clip (no clip.json)")
    if families and not same_render(base, other):
        raise ValueError(
            f"{other} and {base} come from different renders (clip.json gt.render_key) or "
            "training frames: priors can only be swapped between clips of one render"
        )
    meta = json.loads((base / "clip.json").read_text())
    other_meta = json.loads((other / "clip.json").read_text())
    meta["priors"] = {
        "profile": "swapped",
        "families": {
            f: (other_meta if f in families else meta).get("priors", {}).get("profile", "?")
            for f in FAMILIES
        },
        "sources": {f: str(other if f in families else base) for f in FAMILIES},
    }
    (out / "priors").mkdir(parents=True, exist_ok=True)
    tmp = out / "clip.json.tmp"
    tmp.write_text(json.dumps(meta, indent=1))
    os.replace(tmp, out / "clip.json")
    links = {"input": base / "input", "gt": base / "gt"}
    for f in FAMILIES:
        src = other if f in families else base
        links[f"priors/{PRIOR_FILES[f]}"] = src / "priors" / PRIOR_FILES[f]
    for rel, target in links.items():
        link = out / rel
        if link.is_symlink() or link.exists():
            if link.is_symlink() and Path(os.readlink(link)) == target.resolve():
                continue
            link.unlink()
        if target.exists():
            link.symlink_to(target.resolve())
    return out


def score_camera_init(clip_root: Path, run_root: Path) -> Dict[str, float]:
    """Focal error (%), ATE, RPE and dynamic-mask IoU of a run's model/camera_init.pt against the
    clip's ground truth. ATE / RPE over the training frames (the ones the initialisation
    estimates; eval's ate_ba also counts the test frames interpolated between them); the mask IoU
    is eval's (`eval.experiments.score.mask_metrics`)."""
    from eval.experiments.score import mask_metrics
    from eval.metrics.geometry import ate, rpe
    from m4dgs.clip import Clip
    from m4dgs.run import load_torch

    clip = Clip.open(clip_root)
    ci = load_torch(Path(run_root) / "model" / "camera_init.pt")
    frames = clip.train_frames
    cams = clip.load_gt_cameras()
    sel = [cams.frames.tolist().index(g) for g in frames]
    gt_c2w = cams.c2w[sel]
    f_gt = float(cams.K[sel[0], 0, 0])
    est = ci["c2w"].double().numpy()
    r = rpe(est, gt_c2w)
    masks = mask_metrics(Path(run_root), clip) or {}
    return {
        "focal_err_pct": 100 * abs(float(ci["K"][0, 0]) / f_gt - 1),
        "ate": float(ate(est, gt_c2w)),
        "rpe_trans": float(r["rpe_trans"]),
        "rpe_rot_deg": float(r["rpe_rot"]),
        "mask_iou": masks.get("mask_iou"),
    }


def run_combo(clip_root: Path, run_root: Path, preset: str, progress: bool) -> None:
    """The trainer's camera-initialisation phase of the full method on one clip (skipped when the
    run already has it)."""
    from m4dgs.training.pipeline import Trainer

    if (Path(run_root) / "model" / "camera_init.pt").exists():
        return
    trainer = Trainer(clip_root, run_root, preset, "full", device="cpu", progress=progress)
    trainer.run_phase("camera_init")


def _nan(x) -> float:
    return float("nan") if x is None else float(x)


def format_table(rows: List[dict]) -> str:
    head = f"{'scene':26s} {'priors from other':22s} {'f err%':>7s} {'ATE':>8s} {'RPE-t':>8s} "
    head += f"{'RPE-r':>7s} {'IoU':>6s}"
    lines = [head]
    for r in rows:
        lines.append(
            f"{r['scene']:26s} {r['combo']:22s} {r['focal_err_pct']:7.2f} {r['ate']:8.4f} "
            f"{r['rpe_trans']:8.4f} {r['rpe_rot_deg']:7.3f} {_nan(r['mask_iou']):6.3f}"
        )
    lines.append(
        "ATE in GT units after Sim(3) alignment; RPE-t GT units, RPE-r degrees per frame; IoU = "
        "dynamic masks vs gt (pooled)"
    )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="suite folder of the base clips (one per scene)")
    ap.add_argument(
        "--other",
        required=True,
        help="suite folder of the clips with other priors (same renders)",
    )
    ap.add_argument("--scenes", required=True, help="comma-separated scene (clip folder) names")
    ap.add_argument("--out", required=True, help="folder for the assembled clips and the runs")
    ap.add_argument("--preset", default="small", help="training preset whose camera init runs")
    ap.add_argument(
        "--combos",
        default="single",
        help="single: none, each family alone, all three (5 per scene); all: the 8 subsets; "
        "FAMILY[+FAMILY] (e.g. depth): none and that set",
    )
    ap.add_argument(
        "--other-name",
        default="other",
        help="name of the other clips in the combination folders (default: other); give each "
        "--other its own name to share one --out, and so its base runs, between them",
    )
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    try:
        combos = combinations(args.combos)
    except ValueError as e:
        ap.error(str(e))
    out = Path(args.out)
    rows = []
    for scene in [s for s in args.scenes.split(",") if s]:
        base, other = Path(args.base) / scene, Path(args.other) / scene
        for fams in combos:
            name = combo_name(fams, args.other_name)
            try:
                clip = assemble_clip(base, other, fams, out / "clips" / scene / name)
            except ValueError as e:
                print(f"error: {e}", file=sys.stderr)
                return 2
            run = out / "runs" / scene / name
            run_combo(clip, run, args.preset, progress=not args.quiet)
            row = {"scene": scene, "combo": name, "from_other": list(fams)}
            row.update(score_camera_init(clip, run))
            rows.append(row)
            print(f"done {scene} {name}: ATE {row['ate']:.4f}", file=sys.stderr, flush=True)
    print(format_table(rows))
    if args.json:
        from m4dgs.core.io import write_json

        write_json(
            args.json, {"preset": args.preset, "base": args.base, "other": args.other, "rows": rows}
        )
    return 0 if all(math.isfinite(r["ate"]) for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
