"""Whether a row of a campaign meets the small-movers requirement, run by run.

    python bench/movers_requirement.py ROOT SUITE [SUITE ...] --row ROW
        [--movers SCENE,SCENE] [--seeds N] [--first-seed K] [--peak KEY] [--json OUT]

For every run of ROW under ROOT/runs/<suite>/<scene>/ (seed 0 in the folder <row>, seed n in
<row>-seed-n), printed one line each:
- its peak ratio (`highlight_peak_ratio` of metrics.json: the render's largest value over the
  highlight pixels / the truth's, geometric mean over the test frames; with `--peak
  highlight_peak_ratio_resolved`, over the highlight pixels the shortest exposure resolves) and
  whether it lies in the band 0.5-2;
- on the movers' scenes (by default the hard-lit spark and bulb), the median over the test frames of
  the movers / still quotient of bench/mover_hdr.py (1: the movers rendered as bright against the
  rest of the frame as they are) and whether it is 0.5 or more.

A mover is kept when every seed's run keeps half or more of its radiance with its peak in the band.
The requirement is met when every mover is kept and every run's peak is in the band; a run without
highlight pixels (no peak ratio) does not count against it. Which runs count is the choice of SUITE:
the hard-lit suite alone, or with a Syn-Exp-3 suite as well. Exit status: 0 met, 1 not met, 2 a run
is missing or unscored (nothing is decided then)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Dict, List, Optional

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mover_hdr import mover_report  # noqa: E402

from eval.experiments.run_files import resolve_clip_dir  # noqa: E402

MOVERS = ("spark-crossing-lit-static", "bare-bulb-swing-lit-handheld")
BAND = (0.5, 2.0)
KEPT = 0.5


def run_folder(suite_dir: Path, scene: str, row: str, seed: int) -> Path:
    """The run folder of (scene, row, seed) under a suite's folder (the suites' naming)."""
    return suite_dir / scene / (row if seed == 0 else f"{row}-seed-{seed}")


PEAK_KEYS = ("highlight_peak_ratio", "highlight_peak_ratio_resolved")


def check_run(run: Path, mover: bool, peak_key: str = PEAK_KEYS[0]) -> Dict:
    """One run's figures: peak ratio (metrics.json's `peak_key`) and band; for a mover's scene,
    the test quotient's median."""
    out: Dict = {"run": str(run), "status": "ok"}
    metrics = run / "metrics.json"
    if not metrics.is_file():
        out["status"] = "missing" if not run.is_dir() else "unscored"
        return out
    peak = json.loads(metrics.read_text()).get(peak_key)
    peak = None if peak is None or not math.isfinite(float(peak)) else float(peak)
    out["peak_ratio"] = peak
    out["peak_in_band"] = None if peak is None else BAND[0] <= peak <= BAND[1]
    if mover:
        rep = mover_report(run, resolve_clip_dir(run))
        test = rep["renders"].get("test/hdr")
        out["quotient_median"] = None if test is None else test["quotient_q"][1]
        out["kept"] = test is not None and test["quotient_q"][1] >= KEPT
    return out


def check(
    root: Path,
    suites: List[str],
    row: str,
    seeds: int = 2,
    movers=MOVERS,
    first_seed: int = 0,
    peak_key: str = PEAK_KEYS[0],
) -> Dict:
    """Every run of `row` at trainer seeds first_seed .. first_seed + seeds - 1 in `suites` under
    `root`, and the verdict (see the module's text)."""
    runs: List[Dict] = []
    for suite in suites:
        suite_dir = Path(root) / "runs" / suite
        scenes = (
            sorted(p.name for p in suite_dir.iterdir() if p.is_dir()) if suite_dir.is_dir() else []
        )
        for scene in scenes:
            for seed in range(first_seed, first_seed + seeds):
                r = check_run(run_folder(suite_dir, scene, row, seed), scene in movers, peak_key)
                runs.append({"suite": suite, "scene": scene, "seed": seed, **r})
    incomplete = [r for r in runs if r["status"] != "ok"]
    out_of_band = [r for r in runs if r.get("peak_in_band") is False]
    kept = {}
    for m in movers:
        mine = [r for r in runs if r["scene"] == m and r["status"] == "ok"]
        kept[m] = bool(mine) and all(r["kept"] and r["peak_in_band"] is not False for r in mine)
    seen = {r["scene"] for r in runs}
    missing_movers = [m for m in movers if m not in seen]
    if not runs or incomplete or missing_movers:
        verdict = "undecided"
    elif all(kept.values()) and not out_of_band:
        verdict = "met"
    else:
        verdict = "not met"
    return {
        "row": row,
        "suites": suites,
        "peak": peak_key,
        "runs": runs,
        "movers_kept": kept,
        "out_of_band": [f"{r['suite']}/{r['scene']} seed {r['seed']}" for r in out_of_band],
        "missing_movers": missing_movers,
        "verdict": verdict,
    }


def _fmt(x: Optional[float], spec: str = ".3g") -> str:
    return "n/a" if x is None else format(x, spec)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("root", type=Path, help="the campaign's experiment root (runs/ inside)")
    ap.add_argument("suites", nargs="+", help="suites whose runs of ROW count")
    ap.add_argument(
        "--row", required=True, help="the row (variant) to check, e.g. ns-2-chains-held"
    )
    ap.add_argument(
        "--movers",
        default=",".join(MOVERS),
        help="comma-separated scenes whose movers must be kept (default: %(default)s)",
    )
    ap.add_argument("--seeds", type=int, default=2, help="trainer seeds per scene (default: 2)")
    ap.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="the first of them (default: 0; 2 for campaign confirm-movers' seeds 2 and 3)",
    )
    ap.add_argument(
        "--peak",
        choices=PEAK_KEYS,
        default=PEAK_KEYS[0],
        help="the peak ratio of metrics.json to hold to the band (default: %(default)s)",
    )
    ap.add_argument("--json", type=Path, help="also write the report here")
    a = ap.parse_args(argv)
    movers = tuple(s for s in a.movers.split(",") if s)
    rep = check(a.root, a.suites, a.row, a.seeds, movers, a.first_seed, a.peak)
    print(f"| suite | scene | seed | {a.peak} | in band | movers / still (test median) | kept |")
    print("|:---|:---|---:|---:|:---|---:|:---|")
    for r in rep["runs"]:
        if r["status"] != "ok":
            print(f"| {r['suite']} | {r['scene']} | {r['seed']} | {r['status']} | | | |")
            continue
        band = {None: "n/a", True: "yes", False: "NO"}[r["peak_in_band"]]
        q = _fmt(r.get("quotient_median")) if "kept" in r else ""
        kept = ("yes" if r["kept"] else "NO") if "kept" in r else ""
        print(
            f"| {r['suite']} | {r['scene']} | {r['seed']} | {_fmt(r['peak_ratio'])} | {band} "
            f"| {q} | {kept} |"
        )
    kept = ", ".join(f"{m}: {'kept' if k else 'NOT kept'}" for m, k in rep["movers_kept"].items())
    print(f"\nmovers: {kept}")
    if rep["missing_movers"]:
        print(f"no run of the movers' scenes {', '.join(rep['missing_movers'])}")
    if rep["out_of_band"]:
        print(f"peaks outside {BAND[0]}-{BAND[1]}: {'; '.join(rep['out_of_band'])}")
    print(f"requirement for {a.row}: {rep['verdict']}")
    if a.json:
        a.json.write_text(json.dumps(rep, indent=1))
    return {"met": 0, "not met": 1}.get(rep["verdict"], 2)


if __name__ == "__main__":
    sys.exit(main())
