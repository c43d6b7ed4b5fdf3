"""Evidence that reshaping eval moved no number: the outputs of `m4dgs-eval` that read
only the committed runs CSVs, recorded once on the untouched code and compared after every step.

    python bench/shape_check.py --record    # writes bench/shape_check.txt (the baseline)
    python bench/shape_check.py --check     # exit 0 when every output is identical to it

It copies the working tree (without .git and virtual environments) to a temporary folder and, with
that copy as the current folder and on PYTHONPATH, runs:

- both results pages as `make results` makes them (docs/results.md with its figures and the README's
  block, lab/results-generator5.md): sha256 of docs/results.md, lab/results-generator5.md, every
  file under docs/figures/ and lab/figures/results-generator5/, and README.md;
- `pairs` and `repeats` invocations of README.md and docs/ on results/runs.csv: their stdout;
- `table SUITE --root R --no-figures` (Markdown, LaTeX, CSV) on run folders whose metrics.json are
  written from the rows of results/runs.csv, and `table R/runs/SUITE` on such a folder of runs:
  their stdout.

The baseline is a small text file of hashes and outputs; --check prints a unified diff of what
differs. A command may be given as `new args || old args`: the baseline was recorded with `old`
and the check runs `new` where `old` is no longer the same command (e.g. a flag added later that
keeps the old output).
"""

from __future__ import annotations

import argparse
import csv
import difflib
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / "bench" / "shape_check.txt"
SKIP = {".git", ".venv", ".pytest_cache", "__pycache__", ".ruff_cache"}
SKIP_TOP = {"out", "experiments"}  # experiment roots at the top only (eval/experiments/ is code)

# the README's and docs/' own invocations on results/runs.csv
PAIRS_AND_REPEATS = [
    "pairs control-tlr --rows full-tlr-0.1",
    "pairs control-tlr-weight --ref full --metrics ldr_oe_psnr,hdr_tae --by-seed --holm "
    "--rows-differ",
    "pairs paper-main --by-seed",
    "pairs paper-ablation --by-seed",
    "pairs crf --holm --ref hdrnerf --metrics crf_error,hdr_psnr,hdr_tae",
    "pairs control-tlr-scale --rows full-tlr-0.1-paper-schedule "
    "--against control-tlr-priors:full:full-tlr-0.1",
    "pairs priors --by-seed --metrics "
    "ldr_oe_psnr,ldr_ne_psnr,hdr_psnr,hdr_tae,hdr_tce,depth_absrel,track_epe",
    "pairs exposure-noise-draw --ref ev-0.75 --by-seed",
    "pairs control-reproj-priors --ref full-oracle --rows no-reproj-oracle",
    "repeats exposure-schedules:alternating control-schedule-coverage:alternating",
    "repeats control-tlr-grad:full control-tlr-weight:full",
    "repeats exposure-noise:ev-0.75 exposure-noise-draw:ev-0.75",
    "repeats control-tlr:full-tlr-0.1 control-tlr-priors:full-tlr-0.1",
    "repeats priors:full-oracle control-reproj-priors:full-oracle",
    "repeats priors:full control-depth-loss:full --check",
]

# the Makefile's `results` target
RESULTS = [
    ["results"],
    ["results", "--csv", "results/runs-generator5.csv", "--out", "lab/results-generator5.md"]
    + ["--no-readme", "--title", "Results on the generator-5 benchmark (superseded)"],
]

# suites whose tables are printed from run folders made of the CSV's rows
TABLE_SUITES = ["paper-main", "paper-ablation", "control-tlr", "crf", "exposure-noise"]


def _copy_tree(dst: Path) -> None:
    def ignore(d, names):
        top = Path(d).resolve() == ROOT
        return [n for n in names if n in SKIP or (top and n in SKIP_TOP)]

    shutil.copytree(ROOT, dst, ignore=ignore, symlinks=True)


def _eval(cwd: Path, args) -> tuple[int, str]:
    """Run `python -m eval ARGS` (a string split at spaces, or a list) in CWD, the copy on
    PYTHONPATH; (exit status, stdout). Stderr is shown when it fails."""
    argv = args.split() if isinstance(args, str) else list(args)
    env = dict(os.environ, PYTHONPATH=str(cwd), OMP_WAIT_POLICY="PASSIVE", COLUMNS="100")
    p = subprocess.run(
        [sys.executable, "-m", "eval", *argv], cwd=cwd, env=env, capture_output=True, text=True
    )
    if p.returncode:
        sys.stderr.write(f"{' '.join(argv)}: exit {p.returncode}\n{p.stderr}")
    return p.returncode, p.stdout


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _value(text: str):
    if text == "":
        return None
    try:
        return float(text)
    except ValueError:
        return text


def _fake_runs(cwd: Path, root: Path) -> None:
    """ROOT/runs/<suite>/<scene>/<row>[-seed-<n>]/metrics.json from every row of the runs CSV."""
    with open(cwd / "results" / "runs.csv", newline="") as f:
        for r in csv.DictReader(f):
            if r["suite"] not in TABLE_SUITES:
                continue
            seed = int(r["seed"])
            name = r["row"] if seed == 0 else f"{r['row']}-seed-{seed}"
            d = root / "runs" / r["suite"] / r["scene"] / name
            d.mkdir(parents=True, exist_ok=True)
            m = {k: _value(v) for k, v in r.items() if k not in ("suite", "scene", "row", "seed")}
            m["run"] = {"variant": r["variant"], "clip_name": r["scene"]}
            (d / "metrics.json").write_text(json.dumps(m, indent=1, sort_keys=True))


def _split(cmd: str) -> tuple[str, str]:
    """(command to run now, command the baseline names it by)."""
    new, _, old = cmd.partition(" || ")
    return new.strip(), (old or new).strip()


def collect(cwd: Path) -> list[tuple[str, str]]:
    """(section name, text) of every output, in a fixed order."""
    out = []
    # the results pages, as the Makefile's `results` target makes them
    for argv in RESULTS:
        rc, _ = _eval(cwd, argv)
        out.append((f"rc of {' '.join(argv[:3])}", str(rc)))
    hashes = [f"{_sha(cwd / 'README.md')}  README.md"]
    for p in (cwd / "docs" / "results.md", cwd / "lab" / "results-generator5.md"):
        hashes.append(f"{_sha(p)}  {p.relative_to(cwd)}")
    for folder in (cwd / "docs" / "figures", cwd / "lab" / "figures" / "results-generator5"):
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                hashes.append(f"{_sha(p)}  {p.relative_to(cwd)}")
    out.append(("sha256 of the results pages, figures and README", "\n".join(hashes)))
    for cmd in PAIRS_AND_REPEATS:
        new, old = _split(cmd)
        rc, text = _eval(cwd, new)
        out.append((f"{old} (rc {rc})", text))
    root = cwd / "shape-runs"
    _fake_runs(cwd, root)
    tables = []
    for s in TABLE_SUITES:
        tables.append(f"table {s} --root shape-runs --no-figures")
    tables += [
        "table paper-main --root shape-runs --no-figures --format latex",
        "table paper-main --root shape-runs --no-figures --format csv",
        "table shape-runs/runs/control-tlr --no-figures",
    ]
    # `table` prints a compact table by default since eval's reshaping; --columns all is the
    # table of before
    tables = [f"{t} --columns all || {t}" for t in tables]
    for cmd in tables:
        new, old = _split(cmd)
        rc, text = _eval(cwd, new)
        out.append((f"{old} (rc {rc})", text))
    return out


def normalise(text: str) -> str:
    """The temporary copy's path written as <tree> (a table names a run folder of it)."""
    return re.sub(r"/[^ ]*?/shape-check-[A-Za-z0-9_]+/tree", "<tree>", text)


def render(sections: list[tuple[str, str]]) -> str:
    return "".join(
        f"=== {name}\n{text}{'' if text.endswith(chr(10)) else chr(10)}" for name, text in sections
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--record", action="store_true", help="write the baseline")
    g.add_argument("--check", action="store_true", help="compare with the baseline")
    ap.add_argument("--baseline", type=Path, default=BASELINE)
    ap.add_argument("--keep", action="store_true", help="keep the temporary copy (path printed)")
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="shape-check-"))
    try:
        cwd = tmp / "tree"
        _copy_tree(cwd)
        text = normalise(render(collect(cwd)))
    finally:
        if a.keep:
            print(f"kept {tmp}", file=sys.stderr)
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    if a.record:
        a.baseline.write_text(text)
        print(f"wrote {a.baseline} ({len(text.splitlines())} lines)")
        return 0
    base = normalise(a.baseline.read_text())
    if base == text:
        print(f"identical to {a.baseline} ({len(text.splitlines())} lines)")
        return 0
    sys.stdout.writelines(
        difflib.unified_diff(
            base.splitlines(True), text.splitlines(True), str(a.baseline), "now", n=2
        )
    )
    return 1


if __name__ == "__main__":
    sys.exit(main())
