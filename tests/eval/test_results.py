"""`m4dgs-eval export` and `m4dgs-eval results` on fake run folders (metrics.json files with known
values): the CSV holds the runs, merging keeps what it should, and the rendered page matches the
CSV. Every expected number is recomputed here from the CSV with numpy / scipy.stats (means,
Student-t intervals, paired differences via ttest_rel), independently of eval.stats / eval.tables;
nothing here checks the numbers of a real run."""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from scipy import stats

from eval.cli import main

ABL_SCENES = ["lamp-room-orbit", "robot-arm-dolly", "pendulum-lamp-handheld"]
MAIN_SCENES = ["wind-chimes-dolly", "night-street-orbit"]
ABL_ROWS = ["no-video-init", "no-occlusion", "no-cov-invariance", "no-reproj", "no-tlr", "full"]
MAIN_ROWS = ["static-hdr", "ldr-reproj-consecutive", "ldr-reproj", "world-only", "full"]
METRICS = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_ssim", "hdr_tae")
# per-row offsets of (ldr_oe_psnr, ldr_ne_psnr, hdr_psnr, hdr_ssim, hdr_tae) from the full row:
# some agree with the paper, some disagree (no-cov-invariance PSNR, no-tlr TAE), some are noise
OFFSETS = {
    "no-video-init": (-1.0, -1.2, -1.5, -0.02, 0.01),
    "no-occlusion": (-0.3, -0.4, -0.5, -0.01, 0.004),
    "no-cov-invariance": (0.8, 0.9, 0.7, 0.01, 0.0),
    "no-reproj": (0.0, 0.0, 0.0, 0.0, 0.0),
    "no-tlr": (-0.05, 0.02, -0.1, 0.0, -0.01),
    "full": (0.0, 0.0, 0.0, 0.0, 0.0),
    "static-hdr": (-4.0, -4.0, -5.0, -0.05, 0.03),
    "ldr-reproj-consecutive": (-6.0, -6.5, -7.0, -0.1, 0.2),
    "ldr-reproj": (-0.5, -0.5, -0.4, 0.0, 0.001),
    "world-only": (-0.8, -0.7, -1.1, -0.01, 0.005),
}
MISSING = ("paper-ablation", "robot-arm-dolly", "no-reproj", 1)  # a run folder without metrics
CAL_ROWS = ["copy-nearest", "flow-merge"]  # the 2D calibration rows every shipped suite carries


def _value(rng, scene_base, row, k):
    return scene_base[k] + OFFSETS[row][k] + rng.normal(0, [0.15, 0.15, 0.2, 0.003, 0.002][k])


LAMP_FLOORS = {"hdr_tae_floor": 0.1234, "hdr_tae_floor_interior": 0.0712}


def _write_run(root, suite, scene, row, seed, vals, curve_gain=None):
    d = Path(root) / "runs" / suite / scene / (row if seed == 0 else f"{row}-seed-{seed}")
    d.mkdir(parents=True, exist_ok=True)
    code = hashlib.sha256(suite.encode()).hexdigest()  # one code version per suite
    info = {"variant": row, "preset": "small", "code": code, "torch_threads": 1 + seed}
    if row in CAL_ROWS:  # a 2D row's run.json (eval.experiments.calibration_rows)
        info = {"variant": row, "preset": "small", "method": "external", "calibration": row}
    if seed == 0 and row not in CAL_ROWS:  # seed 1's run.json predates the host record
        info["host"] = {
            "machine": "x86_64",
            "cpu": "Some CPU",
            "cpu_capability": "AVX2",
            "gpu": None,
        }
    (d / "run.json").write_text(json.dumps(info))
    if scene == "lamp-room-orbit":  # only this scene's clip says its generator version
        c = Path(root) / "clips" / "syn-exp-3" / scene
        c.mkdir(parents=True, exist_ok=True)
        meta = {"generator": {"tool": "benchgen", "version": 7}, "gt": LAMP_FLOORS}
        (c / "clip.json").write_text(json.dumps(meta))
    if (suite, scene, row, seed) == MISSING:
        return None
    m = dict(vals)
    m.update(
        {
            "ldr_convention": "ldr_png",
            "run": {"variant": row, "preset": "small", "clip_name": scene},
            "per_level": {},
            "conventions": {},
        }
    )
    if curve_gain is not None:
        z = np.linspace(-10, 10, 81)
        y = 1 / (1 + np.exp(-curve_gain * z))
        m["crf_curve"] = {
            "log2_x": z.tolist(),
            "learned": np.stack([y, y, y], 1).tolist(),
            "true": None,
            "crf": "hdrnerf",
        }
    (d / "metrics.json").write_text(json.dumps(m))
    return d


def make_runs(root):
    """paper-ablation: 3 scenes x 6 rows x 2 seeds (one run without metrics); paper-main: 2
    scenes x 5 rows x 1 seed; and each suite's two 2D rows, one prediction for every seed (their
    values from a generator of their own, so that the trained rows' draws stay as they were)."""
    cal_rng = np.random.default_rng(11)
    for suite, scenes, seeds in (("paper-ablation", ABL_SCENES, 2), ("paper-main", MAIN_SCENES, 1)):
        for sc in scenes:
            for row in CAL_ROWS:
                vals = {k: float(cal_rng.uniform(20, 30)) for k in METRICS if k != "hdr_tae"}
                for seed in range(seeds):
                    _write_run(root, suite, sc, row, seed, vals)
    rng = np.random.default_rng(7)
    for suite, scenes, rows, seeds in (
        ("paper-ablation", ABL_SCENES, ABL_ROWS, 2),
        ("paper-main", MAIN_SCENES, MAIN_ROWS, 1),
    ):
        for sc in scenes:
            base = [rng.uniform(25, 33), rng.uniform(24, 32), rng.uniform(28, 36), 0.9, 0.08]
            for seed in range(seeds):
                for i, row in enumerate(rows):
                    vals = {k: _value(rng, base, row, j) for j, k in enumerate(METRICS)}
                    _write_run(
                        root, suite, sc, row, seed, vals, 0.5 + 0.1 * i if seed == 0 else None
                    )


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# --------------------------------------------------------------------------------------------------
# independent statistics
# --------------------------------------------------------------------------------------------------
def mean_ci(xs):
    xs = np.asarray(xs, float)
    h = stats.t.ppf(0.975, len(xs) - 1) * xs.std(ddof=1) / math.sqrt(len(xs))
    return xs.mean(), h


def paired(a: dict, b: dict, with_p: bool = False):
    keys = sorted(set(a) & set(b))
    x, y = np.array([a[k] for k in keys]), np.array([b[k] for k in keys])
    res = stats.ttest_rel(x, y)
    lo, hi = res.confidence_interval(0.95)
    out = float((x - y).mean()), float((hi - lo) / 2), bool(lo > 0 or hi < 0), len(keys)
    return (*out, float(res.pvalue)) if with_p else out


def holm_rejects(pvalues: list, alpha: float = 0.05) -> list:
    """Holm's procedure as a sequence of tests (not adjusted p-values): sort ascending, reject the
    k-th smallest (k = 0, 1, ...) while p <= alpha / (m - k), stop at the first that is not."""
    order = sorted(range(len(pvalues)), key=lambda i: pvalues[i])
    rejected = [False] * len(pvalues)
    for k, i in enumerate(order):
        if pvalues[i] > alpha / (len(pvalues) - k):
            break
        rejected[i] = True
    return rejected


def over_scenes(a: dict, b: dict):
    """Mean over scenes of the per-scene mean paired difference, its t interval over the scene
    means (scipy), and the number of scenes."""
    keys = sorted(set(a) & set(b))
    scenes = sorted({k[0] for k in keys})
    means = np.array([np.mean([a[k] - b[k] for k in keys if k[0] == sc]) for sc in scenes])
    lo, hi = stats.ttest_1samp(means, 0.0).confidence_interval(0.95)
    return float(means.mean()), float((hi - lo) / 2), bool(lo > 0 or hi < 0), len(scenes)


def by_run(csv_rows, suite, row, metric):
    return {
        (r["scene"], int(r["seed"])): float(r[metric])
        for r in csv_rows
        if r["suite"] == suite and r["row"] == row and r["status"] == "scored" and r[metric]
    }


def sign(x):
    return "+" if x > 0 else "-" if x < 0 else "0"


def table_after(text: str, title: str) -> list:
    """The rows of the Markdown table that follows the bold title: a list of cell lists, header
    first."""
    lines = text.splitlines()
    i = lines.index(f"**{title}**")
    out = []
    for ln in lines[i + 2 :]:
        if not ln.startswith("|"):
            break
        out.append([c.strip() for c in ln.strip().strip("|").split("|")])
    return [out[0]] + out[2:]


def unbold(s):
    return s.replace("**", "")


COLS = {  # metric -> (header in the tables, format, arrow)
    "ldr_oe_psnr": ("LDR-OE PSNR", ".2f", "↑"),
    "ldr_ne_psnr": ("LDR-NE PSNR", ".2f", "↑"),
    "hdr_psnr": ("HDR PSNR", ".2f", "↑"),
    "hdr_ssim": ("HDR SSIM", ".4f", "↑"),
    "hdr_tae": ("HDR-TAE", ".4f", "↓"),
}
FINDING_METRICS = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae")


def check_table(table, csv_rows, suite, labels, ref, paper=None):
    """The cells of COLS in a rendered suite table against the CSV (value, Δ, Paper, agree);
    returns how many metric columns were checked."""
    head = table[0]
    assert len(table) == 1 + len(labels)
    checked = {m for m, (name, _, arrow) in COLS.items() if name + arrow in head}
    body = {r[0]: dict(zip(head, r)) for r in table[1:]}
    # the (scene, seed) pair of the missing run is left out for every row: each row is averaged
    # over the pairs on which all rows are scored
    left = {(m[1], m[3]) for m in [MISSING] if m[0] == suite}

    def runs(row, metric):
        return {k: v for k, v in by_run(csv_rows, suite, row, metric).items() if k not in left}

    for row, label in labels.items():
        cells = body[label]
        for metric, (name, fmt, arrow) in COLS.items():
            if name + arrow not in head:
                continue
            vals = runs(row, metric)
            value = unbold(cells[name + arrow])
            if not vals:  # a 2D row has no temporal scores
                assert value == "n/a" and cells[f"Δ {name}"] == "n/a", (row, metric)
                continue
            own = vals
            if row in CAL_ROWS:  # one prediction for every seed: each scene counts once
                first = {}
                for sc, seed in sorted(vals):
                    first.setdefault(sc, (sc, seed))
                own = {k: vals[k] for k in first.values()}
            m, h = mean_ci(list(own.values()))
            assert value == f"{m:{fmt}} ± {h:{fmt}}", (row, metric, value)
            assert cells["n"] == str(len(own))
            if row == ref:
                assert cells[f"Δ {name}"] == "ref"
                continue
            d, dh, excl, _ = paired(vals, runs(ref, metric))
            want = f"{d:+{fmt}} ± {dh:{fmt}}" + ("†" if excl else "")
            assert cells[f"Δ {name}"] == want, (row, metric)
            if paper is None:
                continue
            pfmt = ".2f" if fmt == ".2f" else ".3f"
            pv = paper.get(row, {}).get(metric)
            assert cells[f"Paper {name}"] == ("n/a" if pv is None else f"{pv:{pfmt}}")
            pd = None if pv is None else pv - paper[ref][metric]
            pdir = "n/a" if pd is None else sign(0.0 if abs(pd) < 1e-9 else pd)
            if not excl:
                want = f"{pdir} / n.s. / " + ("n/a" if pd is None else "not significant")
            elif pd is None:
                want = f"n/a / {sign(d)} / n/a"
            elif pdir == "0":
                want = f"0 / {sign(d)} / paper tie"
            else:
                want = f"{pdir} / {sign(d)} / " + ("agree" if pdir == sign(d) else "disagree")
            assert cells[f"{name}: paper / ours / agree"] == want, (row, metric)
    return len(checked)


def paper_values():
    p = Path(__file__).resolve().parents[2] / "eval" / "paper_values.yaml"
    return yaml.safe_load(p.read_text())


# --------------------------------------------------------------------------------------------------
def test_export_merge_results_readme(tmp_path):
    root, csvp = tmp_path / "exp", tmp_path / "results" / "runs.csv"
    make_runs(root)
    cli = CliRunner()
    r = cli.invoke(
        main,
        [
            "export",
            "paper-ablation",
            "--root",
            str(root),
            "--csv",
            str(csvp),
            "--scenes",
            ",".join(ABL_SCENES),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "paper-ablation: 47 scored, 1 without metrics.json" in r.output
    # paper-main without --scenes: only the scenes that have run folders
    r = cli.invoke(main, ["export", "paper-main", "--root", str(root), "--csv", str(csvp)])
    assert r.exit_code == 0, r.output
    rows = read_csv(csvp)
    assert len(rows) == 48 + 14
    assert {r["scene"] for r in rows if r["suite"] == "paper-main"} == set(MAIN_SCENES)
    miss = [r for r in rows if r["status"] == "missing"]
    assert [(r["suite"], r["scene"], r["row"], int(r["seed"])) for r in miss] == [MISSING]
    assert miss[0]["ldr_oe_psnr"] == "" and miss[0]["preset"] == ""
    one = next(r for r in rows if r["row"] == "no-tlr" and r["scene"] == "lamp-room-orbit")
    src = json.loads((root / "runs/paper-ablation/lamp-room-orbit/no-tlr/metrics.json").read_text())
    assert one["ldr_oe_psnr"] == f"{src['ldr_oe_psnr']:.6g}" and one["preset"] == "small"
    assert (
        one["label"] == "(e) w/o temporal luminance regularization" and one["variant"] == "no-tlr"
    )
    assert one["hdr_lpips"] == "" and one["clip_setting"] == "syn-exp-3"
    # provenance from run.json and clip.json; "" where a file does not say
    code = hashlib.sha256(b"paper-ablation").hexdigest()[:12]
    assert (one["code"], one["generator"], one["torch_threads"]) == (code, "7", "1")
    other = next(
        r
        for r in rows
        if r["scene"] != "lamp-room-orbit" and r["seed"] == "1" and r["row"] not in CAL_ROWS
    )
    assert other["generator"] == "" and other["torch_threads"] == "2"
    assert one["host"] == "Some CPU / AVX2" and other["host"] == ""
    assert "mixes" not in r.output
    # a run of another code version in a suite is exported, with a warning naming both versions
    info = root / "runs/paper-main" / MAIN_SCENES[0] / "full" / "run.json"
    d = json.loads(info.read_text())
    d["code"] = "f" * 64
    d["host"] = d["host"] | {"gpu": "Some GPU"}  # ... and trained on another host
    info.write_text(json.dumps(d))
    r = cli.invoke(main, ["export", "paper-main", "--root", str(root), "--csv", str(csvp)])
    assert r.exit_code == 0, r.output
    assert "warning: suite paper-main mixes m4dgs code versions" in r.output
    assert "ffffffffffff (1 runs)" in r.output and "(9 runs)" in r.output
    assert "warning: suite paper-main mixes hosts" in r.output
    assert "Some CPU / AVX2 (9 runs), Some CPU / AVX2 / Some GPU (1 runs)" in r.output
    # the clips' HDR-TAE floors: one row per (scene, generator) whose clip.json records them
    floors = read_csv(tmp_path / "results" / "runs-floors.csv")
    assert floors == [
        {
            "scene": "lamp-room-orbit",
            "generator": "7",
            "hdr_tae_floor": "0.1234",
            "hdr_tae_floor_interior": "0.0712",
        }
    ]
    # the CRF curves: seed-0 runs only (the others have none), mean of RGB at 3 decimals
    crf = read_csv(tmp_path / "results" / "runs-crf.csv")
    assert len(crf) == 3 * 6 + 2 * 5
    c = next(x for x in crf if x["row"] == "full" and x["scene"] == "lamp-room-orbit")
    gain = 0.5 + 0.1 * ABL_ROWS.index("full")
    assert c["crf"] == "hdrnerf" and c["0"] == "0.500"
    assert (
        c["-10"] == f"{1 / (1 + math.exp(10 * gain)):.3f}"
        and c["-1"] == f"{1 / (1 + math.exp(gain)):.3f}"
    )

    # merge: a re-scored run replaces its row, a run whose metrics.json is gone does not replace
    # the scored row, and the other suite's rows stay
    mp = root / "runs/paper-ablation/lamp-room-orbit/full/metrics.json"
    m = json.loads(mp.read_text())
    m["ldr_oe_psnr"] += 1.0
    mp.write_text(json.dumps(m))
    gone = root / "runs/paper-ablation/pendulum-lamp-handheld/no-tlr/metrics.json"
    kept = next(
        r["ldr_oe_psnr"]
        for r in rows
        if r["row"] == "no-tlr" and r["scene"] == "pendulum-lamp-handheld" and r["seed"] == "0"
    )
    gone.unlink()
    r = cli.invoke(
        main,
        [
            "export",
            "paper-ablation",
            "--root",
            str(root),
            "--csv",
            str(csvp),
            "--scenes",
            ",".join(ABL_SCENES),
        ],
    )
    assert r.exit_code == 0 and "46 scored, 2 without metrics.json" in r.output, r.output
    rows = read_csv(csvp)
    assert len(rows) == 62
    full = next(
        r
        for r in rows
        if r["row"] == "full" and r["scene"] == "lamp-room-orbit" and r["seed"] == "0"
    )
    assert full["ldr_oe_psnr"] == f"{m['ldr_oe_psnr']:.6g}"
    tlr = next(
        r
        for r in rows
        if r["row"] == "no-tlr" and r["scene"] == "pendulum-lamp-handheld" and r["seed"] == "0"
    )
    assert tlr["status"] == "scored" and tlr["ldr_oe_psnr"] == kept
    # a wrong root adds nothing
    r = cli.invoke(main, ["export", "priors", "--root", str(tmp_path / "nope"), "--csv", str(csvp)])
    assert r.exit_code == 1 and "no metrics.json found" in r.output
    assert len(read_csv(csvp)) == 62

    # results
    readme = tmp_path / "README.md"
    readme.write_text(
        "# Project\n\nintro\n\n## Results\n\n<!-- results:main:start -->\nstale\n"
        "<!-- results:main:end -->\n\n## Next\n\ntail\n"
    )
    docs = tmp_path / "docs"
    docs.mkdir()
    # the hand-written notes live in the research record, lab/, beside docs/
    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "results-notes.md").write_text("# Notes\n")
    # a stale forest plot of a finding without runs goes; a file named like none of ours stays
    (docs / "figures" / "results").mkdir(parents=True)
    (docs / "figures" / "results" / "finding_priors.png").write_bytes(b"old")
    (docs / "figures" / "results" / "finding_mine.png").write_bytes(b"mine")
    args = [
        "results",
        "--csv",
        str(csvp),
        "--out",
        str(docs / "results.md"),
        "--readme",
        str(readme),
    ]
    r = cli.invoke(main, args)
    assert r.exit_code == 0, r.output
    text = (docs / "results.md").read_text()
    pv = paper_values()
    abl = {row: dict(v) for row, v in pv["ablation"]["rows"].items()}
    from eval.records.suite import load_eval_suite

    s = load_eval_suite("paper-ablation")
    labels = {r.name: r.label for r in s.rows}
    t = table_after(text, "Ablations on Syn-Exp-3 (paper Table 3)")
    assert check_table(t, rows, "paper-ablation", labels, "full", abl) == 4
    t = table_after(text, "Ablations, full metrics")
    assert check_table(t, rows, "paper-ablation", labels, "full") == 5
    main_labels = {r.name: r.label for r in load_eval_suite("paper-main").rows}
    t = table_after(text, "Syn-Exp-3 test frames (paper Table 1)")
    assert check_table(t, rows, "paper-main", main_labels, "full") == 5
    title = (
        "Syn-Exp-3 test frames against the paper's Table 1 (static-hdr ~ GaussHDR, "
        "ldr-reproj-consecutive ~ SplineGS-HDR)"
    )
    t = table_after(text, title)
    main_paper = {row: dict(v) for row, v in pv["main"]["rows"].items()}
    assert check_table(t, rows, "paper-main", main_labels, "full", main_paper) == 4
    # what stands behind each suite
    assert (
        "- Runs: 47 scored of 48 (= 3 scenes x 8 rows x 2 seeds); missing: 1 "
        "(`paper-ablation/robot-arm-dolly/no-reproj-seed-1`)" in text
    )
    assert (
        "- **Incomplete pairs**: the tables and figures use the 5 of 6 (scene, seed) pairs on "
        "which every row with runs is scored (lamp-room-orbit seed 0, robot-arm-dolly seed 0, "
        "pendulum-lamp-handheld seed 0, lamp-room-orbit seed 1, pendulum-lamp-handheld seed 1), "
        "so that every row is compared on the same runs; the 7 scored run(s) of the other pairs "
        "wait for the missing runs above" in text
    )
    assert "- Runs: 14 scored of 14 (= 2 scenes x 7 rows x 1 seeds); missing: 0" in text
    assert text.count("**Incomplete pairs**") == 1  # paper-main is complete
    assert "- Preset: small" in text and "[results-notes.md](../lab/results-notes.md)" in text
    # the hosts: seed 0's run.json records one, seed 1's (older) none
    # (a 2D row records none: 12 runs)
    assert "; host Some CPU / AVX2 (18 runs), not recorded (29 runs)" in text
    # the floor line: paper-ablation's clips are lamp-room-orbit (generator 7, floors recorded)
    # and two scenes whose clips say no generator
    n_abl = len({(r["scene"], r["generator"]) for r in rows if r["suite"] == "paper-ablation"})
    assert (
        "mean 0.123 (0.123-0.123) over 1 of its "
        f"{n_abl} clips; edge-excluded (`gt.hdr_tae_floor_interior`, for `hdr_tae_interior`) "
        "0.071 (0.071-0.071)" in text
    )
    assert "the clips' HDR-TAE floors in `runs-floors.csv`" in text
    assert (
        "| [paper-ablation](#paper-ablation) | 3 of 9 | 8 | 2 | small | 47 of 48 | 0 | 1 |" in text
    )
    # figures
    figs = docs / "figures" / "results"
    for suite in ("paper-ablation", "paper-main"):
        for kind in ("bars", "crf", "tae_psnr", "delta_tae_psnr"):
            p = figs / f"{suite}_{kind}.png"
            assert p.exists() and p.read_bytes()[:4] == b"\x89PNG", p
            assert f"](figures/results/{suite}_{kind}.png)" in text
    # the paired differences behind the delta figure, recomputed from the CSV rows
    from eval.records.runs_csv import read_runs_csv
    from eval.records.suite_data import suite_data
    from eval.report.page_figures import paired_deltas

    got = paired_deltas(suite_data("paper-main", read_runs_csv(csvp)))
    at = {(r["scene"], r["row"]): r for r in rows if r["suite"] == "paper-main"}
    assert sorted(got) == sorted(MAIN_ROWS[:-1])
    for row, pts in got.items():
        assert sorted((p[0], p[1]) for p in pts) == sorted((sc, 0) for sc in MAIN_SCENES)
        for scene, _, dx, dy in pts:
            a, ref = at[(scene, row)], at[(scene, "full")]
            assert dx == pytest.approx(float(a["ldr_oe_psnr"]) - float(ref["ldr_oe_psnr"]))
            assert dy == pytest.approx(float(a["hdr_tae"]) - float(ref["hdr_tae"]))

    # findings: every comparison of the ablation finding recomputed from the CSV
    lines = text.split("## Findings", 1)[1].splitlines()
    fl = [ln for ln in lines if ln.startswith("| ") and not ln.startswith("| row")]
    checked = inside = 0
    over_verdicts = []
    # the Holm family: every comparison of the finding (5 rows x 4 metrics), tested by scipy
    fam = [(row, m) for row in ABL_ROWS[:-1] for m in FINDING_METRICS]
    pv = [
        paired(
            by_run(rows, "paper-ablation", row, m),
            by_run(rows, "paper-ablation", "full", m),
            with_p=True,
        )[4]
        for row, m in fam
    ]
    holm_sig = dict(zip(fam, holm_rejects(pv)))
    holm_verdicts, raw_verdicts, het_p = [], [], []
    for row in ABL_ROWS[:-1]:
        for metric in FINDING_METRICS:
            name, fmt, _ = COLS[metric]
            line = next(
                ln for ln in fl if ln.startswith(f"| {row} | full | {name} |")
            )  # the first table that compares row with full: the ablation finding
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            pd = abl[row][metric] - abl["full"][metric]
            assert cells[3] == format(pd, "+" + (".2f" if fmt == ".2f" else ".3f"))
            d, h, excl, n = paired(
                by_run(rows, "paper-ablation", row, metric),
                by_run(rows, "paper-ablation", "full", metric),
            )
            assert cells[5] == f"{d:+{fmt}} ± {h:{fmt}}" and cells[6] == str(n)
            assert n == (5 if row == "no-reproj" else 6)
            if abs(pd) < 1e-9:
                want = "paper tie"
            elif not excl:
                want = "not significant"
            else:
                want = "agrees" if (d > 0) == (pd > 0) else "disagrees"
            assert cells[7] == want, (row, metric)
            raw_verdicts.append(want)
            if abs(pd) < 1e-9:
                want_h = "paper tie"
            elif not holm_sig[(row, metric)]:
                want_h = "not significant"
            else:
                want_h = "agrees" if (d > 0) == (pd > 0) else "disagrees"
            assert cells[8] == want_h, (row, metric)
            holm_verdicts.append(want_h)
            assert cells[9] == ("yes" if d - h <= pd <= d + h else "no"), (row, metric)
            d2, h2, excl2, k = over_scenes(
                by_run(rows, "paper-ablation", row, metric),
                by_run(rows, "paper-ablation", "full", metric),
            )
            assert cells[10] == f"{d2:+{fmt}} ± {h2:{fmt}}" and cells[11] == str(k) == "3"
            if abs(pd) < 1e-9:
                want2 = "paper tie"
            elif not excl2:
                want2 = "not significant"
            else:
                want2 = "agrees" if (d2 > 0) == (pd > 0) else "disagrees"
            assert cells[12] == want2, (row, metric)
            over_verdicts.append(want2)
            # scenes differ: scipy's one-way ANOVA of the paired differences, scene as the factor
            a_ = by_run(rows, "paper-ablation", row, metric)
            b_ = by_run(rows, "paper-ablation", "full", metric)
            keys = sorted(set(a_) & set(b_))
            groups = [
                [a_[k] - b_[k] for k in keys if k[0] == sc] for sc in sorted({k[0] for k in keys})
            ]
            p_f = float(stats.f_oneway(*groups).pvalue)
            assert cells[13] == ("p < 0.001" if p_f < 0.001 else f"p = {p_f:.3f}"), (row, metric)
            het_p.append(p_f)
            inside += d - h <= pd <= d + h
            checked += 1
    assert checked == 20
    assert f"the paper's Δ lies inside our interval in {inside} of the 20 comparisons" in text
    assert (
        f"Scenes differ (p < 0.05) in {sum(p < 0.05 for p in het_p)} of the 20 comparisons" in text
    )
    # the finding's forest plot draws what its table says
    from eval.report.page_figures import finding_points
    from eval.study.findings import FINDINGS, evaluate_finding

    fig = docs / "figures" / "results" / "finding_ablations.png"
    assert fig.read_bytes()[:4] == b"\x89PNG" and "](figures/results/finding_ablations.png)" in text
    assert not (docs / "figures" / "results" / "finding_priors.png").exists()
    assert (docs / "figures" / "results" / "finding_mine.png").read_bytes() == b"mine"
    f_abl = next(f for f in FINDINGS if f.key == "ablations")
    pts = finding_points(evaluate_finding(f_abl, read_runs_csv(csvp)))
    assert len(pts) == 20
    for p in pts:
        name, fmt, _ = COLS[p.metric]
        row = p.label.split(" - ")[0]
        line = next(ln for ln in fl if ln.startswith(f"| {row} | full | {name} |"))
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        mean, half = (float(x) for x in cells[5].split(" ± "))
        tol = 0.6 * 10 ** -int(fmt[1:-1])  # the cells are rounded to the column's format
        assert abs(p.mean - mean) < tol and abs((p.high - p.low) / 2 - half) < tol
        assert abs(p.paper - float(cells[3])) < 0.6 * 10 ** -min(int(fmt[1:-1]), 3)
        assert p.holm_significant == (cells[8] in ("agrees", "disagrees"))
    assert 0 < inside < 20  # both kinds occur in the fake data
    assert len(set(over_verdicts)) >= 2  # the scene-level verdicts are not all alike
    n_ag = over_verdicts.count("agrees")
    assert f"Over scenes: {n_ag} agree, {over_verdicts.count('disagrees')} disagree" in text
    assert (
        "After Holm's correction over the 20 comparisons with an interval: "
        f"{holm_verdicts.count('agrees')} agree, {holm_verdicts.count('disagrees')} disagree"
        in text
    )
    # the fake data has verdicts that survive the correction and verdicts that do not
    dropped = [a != b for a, b in zip(raw_verdicts, holm_verdicts)]
    assert any(dropped) and any(v in ("agrees", "disagrees") for v in holm_verdicts)
    assert all(b == "not significant" for a, b, x in zip(raw_verdicts, holm_verdicts, dropped) if x)
    assert "| no-cov-invariance | full | LDR-OE PSNR | -0.44 | - (worse) |" in text
    for suite in ("control-points", "exposure-noise", "exposure-schedules", "priors"):
        assert f"**not enough data**: no scored run of suite `{suite}` in the CSV." in text
    # the paper-main finding: full vs each baseline, 2 pairs each
    line = next(ln for ln in fl if ln.startswith("| full | world-only | HDR-TAE |"))
    cells = [c.strip() for c in line.strip().strip("|").split("|")]
    assert cells[6] == "2" and cells[11] == "2"  # 2 (scene, seed) pairs, 2 scenes

    # README: the block is replaced, the rest kept, and a second run changes nothing
    rd = readme.read_text()
    assert rd.startswith("# Project\n\nintro\n\n## Results\n\n<!-- results:main:start -->")
    assert rd.endswith("<!-- results:main:end -->\n\n## Next\n\ntail\n") and "stale" not in rd
    block = rd.split("<!-- results:main:start -->")[1].split("<!-- results:main:end -->")[0]
    assert "[docs/results.md](docs/results.md)" in block and "14 of 14 runs scored" in block
    t = table_after(block, "Syn-Exp-3 test frames (paper Table 1)")
    assert check_table(t, rows, "paper-main", main_labels, "full") == 5
    # the findings at a glance, under the README's table and atop results.md's findings: the
    # ablation finding's counts are those of the scipy Holm verdicts above; 6 pairs at most
    # (robot-arm-dolly's no-reproj lacks seed 1); a finding without runs says so
    glance = (
        "| Each ablation row costs quality (paper Table 3) | `paper-ablation` | 3 x 2 | 6 "
        f"| {holm_verdicts.count('agrees')} | {holm_verdicts.count('disagrees')} "
        f"| {holm_verdicts.count('not significant')} | {holm_verdicts.count('paper tie')} | 0 "
        f"| {inside} of 20 |"
    )
    assert holm_verdicts.count("agrees") and holm_verdicts.count("paper tie")
    assert glance in block and glance in text
    assert "[the findings tables](docs/results.md#findings)" in block
    assert text.index(glance) < text.index("### The full method beats each baseline")
    none = "| `control-points` | no runs | 0 | 0 | 0 | 0 | 0 | 16 | n/a |"
    assert none in block and none in text
    snap = {p: p.read_bytes() for p in [readme, docs / "results.md", *figs.iterdir()]}
    r = cli.invoke(main, args)
    assert r.exit_code == 0, r.output
    assert {p: p.read_bytes() for p in snap} == snap

    # a README without the markers is an error, not a silent skip
    readme.write_text("# no markers\n")
    r = cli.invoke(main, args)
    assert r.exit_code == 1 and "results:main:start" in r.output


def test_export_add_missing_fills_metrics_of_scored_runs_only(tmp_path, monkeypatch):
    import eval.experiments.score as score

    root, csvp = tmp_path / "exp", tmp_path / "runs.csv"
    make_runs(root)
    calls = []

    def fake_add(run_dir, clip=None, write=True):  # stands in for the metric's own computation
        calls.append((Path(run_dir).parts[-2:], Path(clip).name))
        m = json.loads((Path(run_dir) / "metrics.json").read_text())
        m["hdr_tce"] = 0.125
        return m, ["hdr_tce"]

    monkeypatch.setattr(score, "add_missing_metrics", fake_add)
    args = ["export", "paper-ablation", "--root", str(root), "--csv", str(csvp)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert calls == [] and all(not x["hdr_tce"] for x in read_csv(csvp))
    r = CliRunner().invoke(main, args + ["--add-missing"])
    assert r.exit_code == 0, r.output
    rows = [x for x in read_csv(csvp) if x["suite"] == "paper-ablation"]
    scored = [x for x in rows if x["status"] == "scored"]
    folder = {"0": ""}  # seed 0's run folder is the row's name, seed s's <row>-seed-<s>
    assert len(calls) == len(scored) and {c[0] for c in calls} == {
        (x["scene"], x["row"] + folder.get(x["seed"], f"-seed-{x['seed']}")) for x in scored
    }
    assert all(c[1] == c[0][0] for c in calls)  # each run is given its own scene's clip
    assert all(x["hdr_tce"] == "0.125" for x in scored)
    assert all(not x["hdr_tce"] for x in rows if x["status"] != "scored")


def test_results_pending(tmp_path):
    """Without a CSV the page says the runs are pending and every finding and control lacks
    data."""
    readme = tmp_path / "README.md"
    readme.write_text("x\n<!-- results:main:start -->\n<!-- results:main:end -->\n")
    out = tmp_path / "docs" / "results.md"
    r = CliRunner().invoke(
        main,
        [
            "results",
            "--csv",
            str(tmp_path / "runs.csv"),
            "--out",
            str(out),
            "--readme",
            str(readme),
        ],
    )
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert "**The runs are pending**" in text and "does not exist yet" in text
    from eval.study.controls import CONTROLS
    from eval.study.findings import FINDINGS

    assert text.count("**not enough data**") == len(FINDINGS) + len(CONTROLS) == 55
    assert "The result tables are pending" in readme.read_text()
    assert not (tmp_path / "docs" / "figures" / "results").exists() or not any(
        (tmp_path / "docs" / "figures" / "results").iterdir()
    )


def _scored_main_row(rng, scene, name, seed):
    """A scored paper-main CSV row of `name` with random metric values (20-30)."""
    from eval.records.runs_csv import SCORED

    r = {"suite": "paper-main", "scene": scene, "row": name, "seed": seed, "label": name}
    r.update(variant=name, preset="small", status=SCORED, ldr_convention="ldr_png")
    r.update({k: float(rng.uniform(20, 30)) for k in METRICS})
    return r


def test_results_of_a_suite_in_progress(tmp_path):
    """While paper-main runs, the tables compare the (scene, seed) pairs on which every row is
    scored (the runs of the other pairs wait), and the README's block stays pending until one pair
    is complete."""
    from eval.records.runs_csv import write_runs_csv

    rng = np.random.default_rng(3)
    csvp, readme = tmp_path / "runs.csv", tmp_path / "README.md"
    out = tmp_path / "docs" / "results.md"
    args = ["results", "--csv", str(csvp), "--out", str(out), "--readme", str(readme)]
    args.append("--no-figures")

    def row(scene, name, seed):
        return _scored_main_row(rng, scene, name, seed)

    # seed 0 of the first scene: two rows only, so no pair is complete
    rows = [row(MAIN_SCENES[0], n, 0) for n in MAIN_ROWS[:2]]
    write_runs_csv(csvp, rows)
    readme.write_text("x\n<!-- results:main:start -->\n<!-- results:main:end -->\n")
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    block = readme.read_text()
    assert "The result tables are pending" in block and "has 2 scored run(s)" in block
    # both scenes complete at seed 0 (the 2D rows included), one row of seed 1: two complete
    # pairs of three
    rows = [row(sc, n, 0) for sc in MAIN_SCENES for n in MAIN_ROWS + CAL_ROWS]
    rows.append(row(MAIN_SCENES[1], "full", 1))
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    text, block = out.read_text(), readme.read_text()
    assert "the 2 of 4 (scene, seed) pairs" in text and "the 1 scored run(s)" in text
    assert "compares the 2 (scene, seed) pairs" in block and "(1 more run(s)" in block
    from eval.records.suite import load_eval_suite

    labels = {r.name: r.label for r in load_eval_suite("paper-main").rows}
    t = table_after(block, "Syn-Exp-3 test frames (paper Table 1)")
    head = t[0]
    body = {c[0]: dict(zip(head, c)) for c in t[1:]}
    for name in MAIN_ROWS:
        v = [x["ldr_oe_psnr"] for x in rows if x["row"] == name and x["seed"] == 0]
        m, h = mean_ci(v)
        assert body[labels[name]]["n"] == "2"
        assert unbold(body[labels[name]]["LDR-OE PSNR↑"]) == f"{m:.2f} ± {h:.2f}"


def test_a_suite_run_at_later_seeds_only_misses_no_run(tmp_path):
    """A campaign that runs seeds 2 and 3 only (a confirmatory test at seeds no earlier run used):
    the page lists those seeds and counts no run of seeds 0 and 1 as missing."""
    from eval.records.runs_csv import write_runs_csv
    from eval.records.suite_data import suite_data

    rng = np.random.default_rng(4)

    def row(scene, name, seed):
        return _scored_main_row(rng, scene, name, seed)

    rows = [row(sc, n, k) for k in (2, 3) for sc in MAIN_SCENES for n in MAIN_ROWS + CAL_ROWS]
    data = suite_data("paper-main", rows)
    assert data.seeds == [2, 3] and all(e["metrics"] for e in data.entries)
    assert {e["run_dir"].rsplit("/", 1)[1] for e in data.entries if e["row"] == "full"} == {
        "full-seed-2",
        "full-seed-3",
    }
    csvp, out = tmp_path / "runs.csv", tmp_path / "docs" / "results.md"
    write_runs_csv(csvp, rows)
    args = ["results", "--csv", str(csvp), "--out", str(out), "--no-readme", "--no-figures"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    n = len(rows)
    assert "- Trainer seeds: 2 (2, 3)" in out.read_text()
    assert f"- Runs: {n} scored of {n} (= {len(MAIN_SCENES)} scenes x" in out.read_text()


def test_results_lists_failed_runs_and_leaves_their_pair_out(tmp_path):
    """A run whose job failed is a "failed" row with its error: the page counts and lists it, the
    tables leave its (scene, seed) pair out of every row, and a failed row never replaces a scored
    one in a merge (a missing one it does, and a missing one never replaces it)."""
    from eval.records.runs_csv import FAILED, MISSING, SCORED, merge_rows, write_runs_csv

    rng = np.random.default_rng(5)
    csvp, readme = tmp_path / "runs.csv", tmp_path / "README.md"
    out = tmp_path / "docs" / "results.md"
    err = "training: stage2: step 2038: the tone mapper's input ... spans -17.0 .. inf"

    def row(scene, name, status=SCORED):
        r = {"suite": "paper-main", "scene": scene, "row": name, "seed": 0, "label": name}
        r.update(variant=name, preset="small", status=status, ldr_convention="ldr_png")
        if status == SCORED:
            r.update({k: float(rng.uniform(20, 30)) for k in METRICS})
        elif status == FAILED:
            r["error"] = err
        return r

    rows = [row(sc, n) for sc in MAIN_SCENES for n in MAIN_ROWS + CAL_ROWS]
    failed = (MAIN_SCENES[1], "full")
    rows = [r if (r["scene"], r["row"]) != failed else row(*failed, FAILED) for r in rows]
    write_runs_csv(csvp, rows)
    readme.write_text("x\n<!-- results:main:start -->\n<!-- results:main:end -->\n")
    args = ["results", "--csv", str(csvp), "--out", str(out), "--readme", str(readme)]
    r = CliRunner().invoke(main, args + ["--no-figures"])
    assert r.exit_code == 0, r.output
    text = out.read_text()
    n = len(MAIN_SCENES) * len(MAIN_ROWS + CAL_ROWS)
    assert (
        f"| [paper-main](#paper-main) | 2 of 9 | 7 | 1 | small | {n - 1} of {n} | 1 | 0 |" in text
    )
    assert f"scored of {n} (= 2 scenes x 7 rows x 1 seeds); failed: 1; missing: 0" in text
    assert "- **Failed runs** (" in text and f"`paper-main/{failed[0]}/full`: {err}" in text
    assert "the 1 of 2 (scene, seed) pairs" in text
    assert "or are left out with the failed run(s) of their pair" in text
    from eval.records.suite import load_eval_suite

    labels = {x.name: x.label for x in load_eval_suite("paper-main").rows}
    t = table_after(text, "Syn-Exp-3 test frames (paper Table 1)")
    body = {c[0]: dict(zip(t[0], c)) for c in t[1:]}
    for name in MAIN_ROWS:  # every row on the one complete pair: the first scene's value
        v = next(
            x["ldr_oe_psnr"] for x in rows if x["row"] == name and x["scene"] == MAIN_SCENES[0]
        )
        assert body[labels[name]]["n"] == "1"
        assert unbold(body[labels[name]]["LDR-OE PSNR↑"]).startswith(f"{v:.2f}")
    # merging: failed never replaces scored, replaces missing
    scored, fail, miss = row("s", "full"), row("s", "full", FAILED), row("s", "full", MISSING)
    assert merge_rows([scored], [fail]) == [scored]
    assert merge_rows([miss], [fail]) == [fail]
    # ... and a missing row (run folder lost) never replaces a failed one: the CSV is the record
    assert merge_rows([fail], [miss]) == [fail]
    assert merge_rows([fail], [scored]) == [scored]


def test_results_warns_of_runs_that_lack_a_metric_their_row_reports(tmp_path):
    """A row whose runs have a metric in some runs and not in others (a run scored before the
    metric existed, or written back by an older export) is named on the page and in a warning; a
    metric that a row never has (here HDR-TCE of static-hdr), or a dynamic-pixel score that no run
    of a scene has, is not."""
    from eval.records.runs_csv import SCORED, write_runs_csv

    csvp, out = tmp_path / "runs.csv", tmp_path / "results.md"
    args = ["results", "--csv", str(csvp), "--out", str(out), "--no-readme", "--no-figures"]

    def row(scene, name, seed, tce):
        r = {"suite": "paper-main", "scene": scene, "row": name, "seed": seed, "label": name}
        r.update(variant=name, preset="small", status=SCORED, ldr_convention="ldr_png")
        r.update({k: 25.0 + seed for k in METRICS}, hdr_tce=tce)
        return r

    rows = [row(sc, n, s, 0.01) for sc in MAIN_SCENES for n in MAIN_ROWS for s in (0, 1)]
    for r in rows:
        if r["row"] == "static-hdr":
            r["hdr_tce"] = None
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "warning" not in r.output and "Metrics some runs lack" not in out.read_text()
    # an export that did not know hdr_tce wrote back full's and world-only's seed-1 runs
    for r in rows:
        if r["row"] in ("full", "world-only") and r["seed"] == 1:
            r["hdr_tce"] = None
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    # 4 runs (2 rows x 2 scenes at seed 1) of the 16 of the four rows that report it lack it
    assert "warning: suite paper-main: some scored runs lack" in r.output
    assert "hdr_tce present in 12 of 16 runs" in r.output
    assert "- Metrics some runs lack" in out.read_text()
    assert "`hdr_tce` present in 12 of 16 runs" in out.read_text()
    # a whole scene without it still counts: hdr_tce does not depend on what the scene holds
    for r in rows:
        if r["scene"] == MAIN_SCENES[0]:
            r["hdr_tce"] = None
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "hdr_tce present in 6 of 16 runs" in r.output
    # but the dynamic-pixel scores of a scene where nothing moves are not partial: no run of
    # night-street-orbit has dyn_ldr_psnr, every run of the other scene has it
    for r in rows:
        r["hdr_tce"] = None if r["row"] == "static-hdr" else 0.01
        r["dyn_ldr_psnr"] = 20.0 if r["scene"] == MAIN_SCENES[0] else None
        # the held-out views' dynamic-pixel scores too
        r["nv_ldr_oe_dyn_mpsnr"] = 21.0 if r["scene"] == MAIN_SCENES[0] else None
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "warning" not in r.output and "Metrics some runs lack" not in out.read_text()
    # one run of the moving scene without it is partial again, counted over that scene only
    rows[0]["dyn_ldr_psnr"] = None
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "dyn_ldr_psnr present in 9 of 10 runs" in r.output


def test_results_section_gives_the_seed_noise_of_its_runs(tmp_path):
    """The suite's section says how much a run moves with its trainer seed: the root mean square
    seed-1 minus seed-0 difference over the (scene, row) groups, computed here by hand, and the
    largest; no line for a suite with one seed."""
    from eval.records.runs_csv import write_runs_csv

    csvp, out = tmp_path / "runs.csv", tmp_path / "results.md"
    args = ["results", "--csv", str(csvp), "--out", str(out), "--no-readme", "--no-figures"]
    rng = np.random.default_rng(5)

    def row(scene, name, seed):
        return _scored_main_row(rng, scene, name, seed)

    rows = [row(sc, n, 0) for sc in MAIN_SCENES for n in MAIN_ROWS]
    write_runs_csv(csvp, rows)
    assert CliRunner().invoke(main, args).exit_code == 0
    assert "Seed noise" not in out.read_text()
    rows += [row(sc, n, 1) for sc in MAIN_SCENES for n in MAIN_ROWS]
    # a 2D row's seed 1 is a copy of its seed 0 (one prediction for every seed): not seed noise
    for sc in MAIN_SCENES:
        cal = dict(row(sc, "copy-nearest", 0), variant="calibration")
        rows += [cal, dict(cal, seed=1)]
    write_runs_csv(csvp, rows)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    by = {(x["scene"], x["row"], x["seed"]): x for x in rows}
    d = [
        by[(sc, n, 1)]["ldr_oe_psnr"] - by[(sc, n, 0)]["ldr_oe_psnr"]
        for sc in MAIN_SCENES
        for n in MAIN_ROWS
    ]
    rms = math.sqrt(sum(x * x for x in d) / len(d))
    line = next(x for x in out.read_text().splitlines() if x.startswith("- Seed noise"))
    groups = len(MAIN_SCENES) * len(MAIN_ROWS)
    assert f"over {groups} (scene, row) groups" in line
    assert f"LDR-OE PSNR {rms:.2f} (largest {max(abs(x) for x in d):.2f})" in line


@pytest.mark.parametrize(
    "v, text",
    [
        (None, ""),
        (float("nan"), ""),
        (34.751234567, "34.7512"),
        (0.0571234567, "0.0571235"),
        (1234567.4, "1234567"),
        (float("inf"), "inf"),
    ],
)
def test_number_format(v, text):
    from eval.records.runs_csv import fmt_number, parse_number

    assert fmt_number(v) == text
    if text:
        assert parse_number(text) == pytest.approx(v, rel=1e-5)


def _committed_tree(repo: Path):
    """(read(rel) -> bytes or None, listing(folder) -> file names) of the files as committed at HEAD
    when `repo` is a git checkout (a campaign running in the checkout rewrites results/runs.csv
    between commits), else of the working tree (an unpacked source tree)."""
    import subprocess

    def git(*args):
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True)

    if git("rev-parse", "--verify", "-q", "HEAD").returncode != 0:
        return (
            lambda rel: (repo / rel).read_bytes() if (repo / rel).exists() else None,
            lambda rel: sorted(p.name for p in (repo / rel).glob("*")),
        )

    def read(rel):
        r = git("show", f"HEAD:{rel}")
        return r.stdout if r.returncode == 0 else None

    def listing(rel):
        out = git("ls-tree", "--name-only", "HEAD", f"{rel}/").stdout.decode()
        return sorted(Path(line).name for line in out.splitlines() if line)

    return read, listing


def _page_command(page: str) -> list:
    """The `m4dgs-eval results ...` arguments a generated page states in its first comment."""
    import re
    import shlex

    m = re.search(r"<!-- generated by `m4dgs-eval (results[^`]*)` from ", page)
    assert m, "the page does not state the command that made it"
    return shlex.split(m.group(1))


def test_committed_results_pages_are_regenerated_from_the_committed_csvs(tmp_path, monkeypatch):
    """Every committed docs/results*.md and lab/results*.md (the main page and the page of the
    superseded generator-5 runs), its figures and, for the main page, the README's results block
    are what the command written in the page makes from the committed CSV (a stale page, a CSV
    edited without regenerating the page, or a page whose stated command does not make it, fails
    here). The numbers themselves are the CSV's; their rendering is tested above."""
    repo = Path(__file__).resolve().parents[2]
    read, listing = _committed_tree(repo)
    pages = [
        f"{d}/{n}"
        for d in ("docs", "lab")
        for n in listing(d)
        if n.startswith("results") and n.endswith(".md")
    ]
    pages = [p for p in pages if p != "lab/results-notes.md"]
    if read("results/runs.csv") is None or "docs/results.md" not in pages:
        pytest.skip("no committed results/runs.csv")
    csvs = [f"results/{n}" for n in listing("results") if n.endswith(".csv")]
    for rel in csvs + ["lab/results-notes.md", "README.md"]:
        data = read(rel)
        if data is not None:
            (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / rel).write_bytes(data)
    monkeypatch.chdir(tmp_path)
    # only the figures' names are compared here (their drawing is tested above): an empty file
    # instead of the PNG saves the minute that encoding the page's hundred-odd figures takes
    import eval.figures
    import eval.report.page_figures

    def name_only(fig, path):
        eval.figures.pyplot().close(fig)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"")
        return path

    monkeypatch.setattr(eval.figures, "save_png", name_only)
    monkeypatch.setattr(eval.report.page_figures, "save_png", name_only)
    for page in pages:
        committed = read(page).decode()
        args = _page_command(committed)
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
        out = Path(args[args.index("--out") + 1]) if "--out" in args else Path("docs/results.md")
        # the suite definitions are linked where the package is: here, outside tmp_path
        made = (tmp_path / out).read_text()
        made = made.replace(os.path.relpath(repo / "eval", tmp_path / out.parent) + "/", "../eval/")
        assert made == committed, f"{page} is stale: run the command at its top and commit"
        figs_rel = f"{out.parent}/figures/{out.stem}"
        figs = sorted(p.name for p in (tmp_path / figs_rel).glob("*.png"))
        assert figs == [n for n in listing(figs_rel) if n.endswith(".png")], page
    assert (tmp_path / "README.md").read_bytes() == read("README.md")


def test_results_page_title_own_figures_and_stated_command(tmp_path, monkeypatch):
    """A second page from another CSV: its heading, its own figure folder (PNGs of suites no longer
    in its CSV are removed, the main page's folder is not touched), the README left alone with
    --no-readme, and the command stated in the page makes the same page again."""
    from eval.records.runs_csv import write_runs_csv as write_csv

    monkeypatch.chdir(tmp_path)
    rows = _control_rows(np.random.default_rng(5))
    Path("results").mkdir()
    Path("docs").mkdir()
    Path("README.md").write_text("# x\n")
    write_csv("results/runs-old.csv", rows)
    main_figs = Path("docs/figures/results")
    main_figs.mkdir(parents=True)
    (main_figs / "keep.png").write_bytes(b"x")
    # a PNG in the page's folder that is not named like a results figure of a shipped suite stays
    figs = Path("docs/figures/results-old")
    figs.mkdir(parents=True)
    for other in ("diagram.png", "my-suite_bars.png"):
        (figs / other).write_bytes(b"x")
    args = ["results", "--csv", "results/runs-old.csv", "--out", "docs/results-old.md"]
    args += ["--no-readme", "--title", "Old runs (superseded)"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    page = Path("docs/results-old.md").read_text()
    assert page.startswith("# Old runs (superseded)\n")
    assert _page_command(page) == args
    foreign = ["diagram.png", "my-suite_bars.png"]
    made = sorted(p.name for p in figs.glob("*.png") if p.name not in foreign)
    assert any(n.startswith("control-video-init-scale_") for n in made), made
    assert (main_figs / "keep.png").exists() and Path("README.md").read_text() == "# x\n"
    # the scale suite leaves the CSV: its figures leave the folder, the others stay
    write_csv("results/runs-old.csv", [r for r in rows if r["suite"] != "control-video-init-scale"])
    r = CliRunner().invoke(main, _page_command(page))
    assert r.exit_code == 0, r.output
    after = sorted(p.name for p in figs.glob("*.png"))
    kept = [n for n in made if not n.startswith("control-video-init-scale_")]
    assert after == sorted(kept + foreign)
    assert after and Path("docs/results-old.md").read_text() != page


# --------------------------------------------------------------------------------------------------
# controls: differences in differences
# --------------------------------------------------------------------------------------------------
def _control_rows(rng, code_scale="c0"):
    """CSV rows of the two ablation-(a) control suites: 3 scenes x 2 seeds; (a)'s lead is ~+1 dB
    on realistic priors, ~0 on oracle priors, ~+0.8 with the paper's schedule. The scale suite
    misses one (scene, seed), so its change is paired over 5 keys."""
    scenes = ["lamp-room-orbit", "pendulum-lamp-handheld", "robot-arm-dolly"]
    lead = {
        ("control-video-init-priors", "no-video-init"): 1.0,
        ("control-video-init-priors", "no-video-init-oracle"): 0.0,
        ("control-video-init-scale", "no-video-init-paper-schedule"): 0.8,
    }
    suites = {
        "control-video-init-priors": [
            "full",
            "no-video-init",
            "full-oracle",
            "no-video-init-oracle",
        ],
        "control-video-init-scale": ["full-paper-schedule", "no-video-init-paper-schedule"],
    }
    rows = []
    for suite, names in suites.items():
        for scene in scenes:
            for seed in (0, 1):
                if suite == "control-video-init-scale" and (scene, seed) == (scenes[2], 1):
                    continue
                base = 30.0 + 2 * rng.random()
                for name in names:
                    oe = base + lead.get((suite, name), 0.0) + rng.normal(0, 0.3)
                    code = code_scale if suite.endswith("scale") else "c0"
                    rows.append(
                        dict(suite=suite, scene=scene, row=name, seed=seed, status="scored")
                        | dict(generator="6", code=code, ldr_oe_psnr=oe, ldr_ne_psnr=oe - 0.5)
                        | dict(hdr_psnr=38 + rng.normal(0, 1), hdr_tae=0.1 + rng.normal(0, 0.01))
                    )
    return rows


def _t_interval(x):
    x = np.asarray(x, float)
    return x.mean(), stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))


def _section(text, key):
    """The Controls section of control `key`."""
    from eval.study.controls import CONTROLS

    title = next(c.title for c in CONTROLS if c.key == key)
    return text.split(f"### {title}", 1)[1].split("\n### ", 1)[0]


def _table_row(text, key, metric_header):
    block = _section(text, key)
    for line in block.splitlines():
        if line.startswith(f"| {metric_header} |"):
            return [c.strip() for c in line.strip("|").split("|")]
    raise AssertionError(f"no row {metric_header} under control {key}")


def _parse_interval(cell):
    mean, rest = cell.split(" ± ")
    half, n = rest.split(" (n = ")
    return float(mean), float(half.rstrip("†")), int(n.rstrip(")")), half.endswith("†")


def test_controls_are_differences_in_differences(tmp_path):
    """The Controls section: each effect's mean and interval, and the change paired over the keys
    all four rows have, recomputed here with numpy / scipy from the same rows (written to a CSV
    and read back as `m4dgs-eval results` does)."""
    from eval.records.runs_csv import read_runs_csv, write_runs_csv
    from eval.report.page import _is_results_figure
    from eval.report.page_figures import controls_figure, controls_figure_data
    from eval.study.controls import NO_CHANGE, SHRINKS, controls_markdown
    from eval.study.findings import NO_DATA

    rng = np.random.default_rng(7)
    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, _control_rows(rng))
    rows = read_runs_csv(csv_path)
    text = controls_markdown(rows, "results-notes.md")

    def vals(suite, row):
        return {
            (r["scene"], r["seed"]): r["ldr_oe_psnr"]
            for r in rows
            if r["suite"] == suite and r["row"] == row
        }

    P, S = "control-video-init-priors", "control-video-init-scale"
    real = {k: v - vals(P, "full")[k] for k, v in vals(P, "no-video-init").items()}
    oracle = {k: v - vals(P, "full-oracle")[k] for k, v in vals(P, "no-video-init-oracle").items()}
    paper = {
        k: v - vals(S, "full-paper-schedule")[k]
        for k, v in vals(S, "no-video-init-paper-schedule").items()
    }
    assert len(real) == 6 and len(paper) == 5
    for key, ctrl in (("video-init-priors", oracle), ("video-init-scale", paper)):
        cells = _table_row(text, key, "LDR-OE PSNR")
        for cell, values in ((cells[1], real), (cells[2], ctrl)):
            mean, half, n, _ = _parse_interval(cell)
            em, eh = _t_interval(list(values.values()))
            assert n == len(values) and mean == pytest.approx(em, abs=0.006)
            assert half == pytest.approx(eh, abs=0.006)
        keys = [k for k in ctrl if k in real]
        mean, half, n, dag = _parse_interval(cells[3])
        em, eh = _t_interval([ctrl[k] - real[k] for k in keys])
        assert n == len(keys) and mean == pytest.approx(em, abs=0.006)
        assert half == pytest.approx(eh, abs=0.006)
        assert dag == (abs(em) > eh)
        expect = NO_CHANGE if abs(em) <= eh else _reading(np.mean(list(real.values())), em)
        assert cells[4] == expect
    # oracle priors remove the ~1 dB lead: the change is resolved and the lead shrinks
    assert _table_row(text, "video-init-priors", "LDR-OE PSNR")[4] == SHRINKS
    # after Holm: the change's scipy p-values over the control's four metrics, Holm's procedure
    metrics = {"ldr_oe_psnr": "LDR-OE PSNR", "ldr_ne_psnr": "LDR-NE PSNR"}
    metrics |= {"hdr_psnr": "HDR PSNR", "hdr_tae": "HDR-TAE"}

    def effect(suite, row, ref, metric):
        def of(name):
            return {
                (r["scene"], r["seed"]): r[metric]
                for r in rows
                if (r["suite"], r["row"]) == (suite, name)
            }

        a, b = of(row), of(ref)
        return {k: a[k] - b[k] for k in a if k in b}

    readings = []
    for key, ctrl_rows in (
        ("video-init-priors", (P, "no-video-init-oracle", "full-oracle")),
        ("video-init-scale", (S, "no-video-init-paper-schedule", "full-paper-schedule")),
    ):
        pv, want = [], []
        for m in metrics:
            b, c = effect(P, "no-video-init", "full", m), effect(*ctrl_rows, m)
            d = [c[k] - b[k] for k in c if k in b]
            pv.append(stats.ttest_1samp(d, 0.0).pvalue)
            want.append((np.mean(d), np.mean(list(b.values()))))
        for (m, name), keep, (dm, bm) in zip(metrics.items(), holm_rejects(pv), want):
            cell = _table_row(text, key, name)[5]
            up = _reading(bm, dm)
            assert cell == (up if keep else NO_CHANGE), (key, m)
            readings.append(cell)
    assert SHRINKS in readings and NO_CHANGE in readings  # both kinds occur
    # the split control's suite is not in these rows
    split = _section(text, "video-init-split")
    assert "not enough data" in split and "`control-video-init`" in split
    assert "Different code versions" not in text
    # the overview figure draws the controls with data, each effect as its table states it, the
    # marker filled exactly where the table's "after Holm" reads a change
    data = controls_figure_data(rows)
    assert [c.key for c, _ in data] == ["video-init-priors", "video-init-scale"]
    for c, res in data:
        r = res["ldr_oe_psnr"]
        cells = _table_row(text, c.key, "LDR-OE PSNR")
        assert _parse_interval(cells[1])[0] == pytest.approx(r.base.mean, abs=0.006)
        assert _parse_interval(cells[2])[0] == pytest.approx(r.control.mean, abs=0.006)
        assert (r.reading_holm not in (NO_CHANGE, NO_DATA)) == (cells[5] != NO_CHANGE)
    png = controls_figure(rows, tmp_path / "controls.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and _is_results_figure("controls.png")
    assert controls_figure([], tmp_path / "none.png") is None
    linked = controls_markdown(rows, None, "figures/controls.png")
    assert "![controls](figures/controls.png)" in linked and "![" not in text


def test_host_label():
    from eval.experiments.export import host_label

    cpu = {"machine": "x86_64", "cpu": "AMD EPYC", "cpu_capability": "AVX2", "gpu": None}
    assert host_label(cpu) == "AMD EPYC / AVX2"
    assert host_label(cpu | {"gpu": "NVIDIA H200"}) == "AMD EPYC / AVX2 / NVIDIA H200"
    assert host_label(cpu | {"cpu": ""}) == "AVX2"
    assert host_label(None) == host_label({}) == ""


def test_controls_flag_different_hosts_only_where_both_sides_recorded_theirs():
    from eval.study.controls import controls_markdown

    rows = _control_rows(np.random.default_rng(3))
    for r in rows:  # the priors suite on one machine; the scale suite's runs say nothing
        if r["suite"] == "control-video-init-priors":
            r["host"] = "CPU A / AVX2"
    text = controls_markdown(rows, None)
    assert "Different hosts" not in text  # an unrecorded side is not a difference
    for r in rows:
        if r["suite"] == "control-video-init-scale":
            r["host"] = "CPU B / AVX512"
    scale = _section(controls_markdown(rows, None), "video-init-scale")
    assert "**Different hosts**: base CPU A / AVX2, control CPU B / AVX512" in scale
    priors = _section(controls_markdown(rows, None), "video-init-priors")
    assert "Different hosts" not in priors


def test_controls_flag_different_code_versions(tmp_path):
    from eval.study.controls import controls_markdown

    rows = _control_rows(np.random.default_rng(3), code_scale="c1")
    text = controls_markdown(rows, None)
    scale, priors = _section(text, "video-init-scale"), _section(text, "video-init-priors")
    assert "**Different code versions**: base c0, control c1" in scale
    assert "Different code versions" not in priors
    # a control whose own rows have no scored run yet (its suite has others) compares no versions
    pending = [r for r in rows if r["row"] not in ("no-video-init-oracle", "full-oracle")]
    priors = _section(controls_markdown(pending, None), "video-init-priors")
    assert "not enough data" in priors and "Different" not in priors


def _reading(base_mean, change_mean):
    """The expected reading of a resolved change, from the effect's magnitude before and after."""
    from eval.study.controls import GROWS, REVERSES, SHRINKS

    before, after = base_mean, base_mean + change_mean
    if abs(after) < abs(before):
        return SHRINKS
    return GROWS if np.sign(after) == np.sign(before) else REVERSES


def test_control_reading():
    from eval.stats import Interval
    from eval.study.controls import GROWS, NO_CHANGE, REVERSES, SHRINKS, control_reading
    from eval.study.findings import NO_DATA

    base = Interval(1.0, 0.5, 4)
    assert control_reading(base, Interval(-0.9, 0.5, 4)) == SHRINKS
    assert control_reading(base, Interval(0.9, 0.5, 4)) == GROWS
    assert control_reading(base, Interval(0.3, 0.5, 4)) == NO_CHANGE
    assert control_reading(Interval(-1.0, 0.5, 4), Interval(0.9, 0.5, 4)) == SHRINKS
    # past 0 but smaller than before: shrinks; past 0 and larger: reverses
    assert control_reading(base, Interval(-1.5, 0.5, 4)) == SHRINKS
    assert control_reading(base, Interval(-2.5, 0.5, 4)) == REVERSES
    # an effect near 0 that becomes large (control-tlr's LDR PSNR: -0.12 dB, then +1.51 dB)
    assert control_reading(Interval(-0.12, 1.13, 4), Interval(1.63, 1.14, 4)) == REVERSES
    assert control_reading(Interval(0.08, 0.71, 4), Interval(1.48, 0.72, 4)) == GROWS
    assert control_reading(base, Interval(0.9, None, 1)) == NO_DATA
    assert control_reading(None, Interval(0.9, 0.5, 4)) == NO_DATA


def test_floor_line_mean_and_range_over_the_suites_clips(tmp_path):
    """floors_text: mean and range over the (scene, generator) clips of the suite's scored runs
    that have a recorded floor, recomputed with numpy; clips of another generator version do not
    count; no line without any floor."""
    from eval.records.runs_csv import read_runs_csv, write_runs_csv
    from eval.records.suite_data import suite_data
    from eval.report.page import floors_text

    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, _control_rows(np.random.default_rng(3)))
    data = suite_data("control-video-init-priors", read_runs_csv(csv_path))
    floors = {
        ("lamp-room-orbit", "6"): {"hdr_tae_floor": 0.118, "hdr_tae_floor_interior": 0.068},
        ("pendulum-lamp-handheld", "6"): {"hdr_tae_floor": 0.126, "hdr_tae_floor_interior": None},
        ("robot-arm-dolly", "5"): {"hdr_tae_floor": 0.5, "hdr_tae_floor_interior": 0.5},
    }
    line = floors_text(data, floors)
    f = np.array([0.118, 0.126])
    assert f"mean {f.mean():.3f} ({f.min():.3f}-{f.max():.3f}) over 2 of its 3 clips;" in line
    assert line.endswith("0.068 (0.068-0.068)")
    assert floors_text(data, {}) is None
    # one scene's clips of two generator versions (2D rows made on newer clips) are two clips,
    # and the line says how many scenes they are
    rows = read_runs_csv(csv_path)
    rows.append(dict(rows[0], row="copy-nearest", variant="calibration", generator="7"))
    floors[(rows[0]["scene"], "7")] = {"hdr_tae_floor": 0.119, "hdr_tae_floor_interior": 0.069}
    line = floors_text(suite_data("control-video-init-priors", rows), floors)
    f = np.array([0.118, 0.126, 0.119])
    assert (
        f"mean {f.mean():.3f} ({f.min():.3f}-{f.max():.3f}) over 3 of its 4 clips "
        "(3 scenes, clips of 2 generator versions);"
    ) in line


def test_every_control_names_rows_its_suites_have():
    """A control reads four rows by name; a name its suite file lacks would leave the control
    at "not enough data" forever instead of failing."""
    from eval.records.suite import load_eval_suite
    from eval.study.controls import CONTROLS

    for c in CONTROLS:
        for e in (c.base, c.control):
            rows = {r.name for r in load_eval_suite(e.suite).rows}
            assert {e.row, e.ref} <= rows, (c.key, e.suite, {e.row, e.ref} - rows)


def test_bars_leave_no_slot_for_a_row_without_values(tmp_path, monkeypatch):
    """The per-scene bars give each row with a value one slot: a row the CSV has no value of
    (a 2D row never made on a superseded page's clips) leaves no gap, and each bar's height is its
    row's mean over the seeds."""
    import eval.report.page_figures as pf
    from eval.records.runs_csv import SCORED
    from eval.records.suite_data import suite_data

    figs = []
    monkeypatch.setattr(pf, "save_png", lambda fig, path: figs.append(fig) or Path(path))
    rows = []
    for sc in MAIN_SCENES:
        for k, name in enumerate(MAIN_ROWS):
            for seed in (0, 1):
                r = {"suite": "paper-main", "scene": sc, "row": name, "seed": seed, "label": name}
                r.update(variant=name, preset="small", status=SCORED, ldr_convention="ldr_png")
                r["ldr_oe_psnr"] = 20.0 + k + seed
                rows.append(r)
    data = suite_data("paper-main", rows)
    assert set(MAIN_ROWS) < set(data.row_names)  # the suite's 2D rows have no runs here
    pf.bars_figure(data, tmp_path / "bars.png")
    bars = [p for p in figs[0].axes[0].patches]
    assert len(bars) == len(MAIN_SCENES) * len(MAIN_ROWS)
    width = 0.8 / len(MAIN_ROWS)
    assert all(abs(b.get_width() - 0.9 * width) < 1e-9 for b in bars)
    assert sorted({round(b.get_height(), 6) for b in bars}) == [
        20.5 + k for k in range(len(MAIN_ROWS))
    ]
