"""Do two checkouts train the same model? Trains one clip with each checkout's m4dgs (torch on one
thread, each in its own process, one after the other) and compares every tensor of the phase
outputs (model/camera_init.pt, stage1.pt, v2w.pt, final.pt) and every logged value of log.jsonl
but the step times.

    python bench/same_bits.py OLD_CHECKOUT NEW_CHECKOUT CLIP [--preset tiny] [--variant full]
                              [--out DIR] [--set KEY=VALUE ...]

OLD_CHECKOUT / NEW_CHECKOUT are folders holding an m4dgs package (a git worktree of another commit,
e.g. `git worktree add /tmp/old COMMIT`). Prints one line per file (tensors compared, tensors that
differ and the first few names) and exits 0 when everything is equal, 1 otherwise. Use it before
letting a campaign's later steps run on newer code than its earlier ones: equal bits mean the rows
of the two code versions are the same runs, not two draws. `--set` applies a config override to
both trainings (dotted key, as `m4dgs train --set`), `--variant` trains another variant (`m4dgs
variants`); a phase the variant does not run (stage 1 of world-only) is left out of the comparison
when neither run has its file.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

PHASE_FILES = ("camera_init.pt", "stage1.pt", "v2w.pt", "final.pt")
TIME_KEYS = ("sec",)

TRAIN = """
import sys, torch
torch.set_num_threads(1)
from m4dgs.training.pipeline import train
overrides = dict(kv.split("=", 1) for kv in sys.argv[5:])
train(sys.argv[1], sys.argv[2], preset=sys.argv[3], variant=sys.argv[4],
      overrides=overrides or None, progress=False)
"""


def train_with(checkout: Path, clip: Path, out: Path, preset: str, sets, variant="full") -> None:
    """One training of `clip` into `out` with the m4dgs of `checkout`, in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(checkout), OMP_WAIT_POLICY="PASSIVE")
    cmd = [sys.executable, "-c", TRAIN, str(clip), str(out), preset, variant, *sets]
    r = subprocess.run(cmd, cwd=checkout, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"training with {checkout} failed:\n{r.stderr[-3000:]}")


def compare_models(a_path: Path, b_path: Path) -> tuple[int, list]:
    """(tensors compared, names of those that differ or exist on one side only)."""
    import torch

    from m4dgs.run import checkpoint_tensors, load_torch

    a, b = checkpoint_tensors(load_torch(a_path)), checkpoint_tensors(load_torch(b_path))
    differ = sorted(set(a) ^ set(b))
    differ += [
        k
        for k in sorted(set(a) & set(b))
        if a[k].shape != b[k].shape or not torch.equal(a[k], b[k])
    ]
    return len(set(a) | set(b)), differ


def compare_logs(a_path: Path, b_path: Path) -> tuple[int, list]:
    """(log records compared, "record:key" of the values that differ, step times apart)."""
    a = [json.loads(line) for line in a_path.read_text().splitlines() if line.strip()]
    b = [json.loads(line) for line in b_path.read_text().splitlines() if line.strip()]
    differ = [] if len(a) == len(b) else [f"length {len(a)} != {len(b)}"]
    for i, (x, y) in enumerate(zip(a, b)):
        for k in sorted(set(x) | set(y)):
            if k not in TIME_KEYS and x.get(k) != y.get(k):
                differ.append(f"{i}:{k}")
    return max(len(a), len(b)), differ


def compare_runs(old: Path, new: Path, say=print) -> bool:
    """Compare two run folders' phase files and logs, one line each through `say`; True when all
    are equal. A phase file in neither run (a phase the variant does not run) is left out; one in
    a single run is a difference."""
    equal = True
    for f in PHASE_FILES:
        have = [(run / "model" / f).exists() for run in (old, new)]
        if not any(have):
            say(f"{f}: in neither run (a phase the variant does not run)")
            continue
        if not all(have):
            equal = False
            say(f"{f}: only in the {'old' if have[0] else 'new'} run")
            continue
        n, differ = compare_models(old / "model" / f, new / "model" / f)
        equal &= not differ
        say(f"{f}: {n} tensors, {len(differ)} differ {differ[:4]}")
    n, differ = compare_logs(old / "log.jsonl", new / "log.jsonl")
    equal &= not differ
    say(f"log.jsonl: {n} records, {len(differ)} values differ {differ[:4]}")
    return equal


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", type=Path, help="checkout holding the first m4dgs package")
    ap.add_argument("new", type=Path, help="checkout holding the second m4dgs package")
    ap.add_argument("clip", type=Path, help="clip folder to train on")
    ap.add_argument("--preset", default="tiny", choices=["tiny", "small", "paper"])
    ap.add_argument("--variant", default="full", help="variant to train (`m4dgs variants`)")
    ap.add_argument(
        "--out", type=Path, default=None, help="folder for the two runs (default: temp)"
    )
    ap.add_argument("--set", dest="sets", action="append", default=[], help="KEY=VALUE override")
    args = ap.parse_args(argv)
    for c in (args.old, args.new):
        if not (c / "m4dgs" / "__init__.py").exists():
            ap.error(f"{c}: no m4dgs package there")
    out = args.out or Path(tempfile.mkdtemp(prefix="same_bits_"))
    runs = {}
    for name, checkout in (("old", args.old), ("new", args.new)):
        runs[name] = out / name
        train_with(
            checkout.resolve(),
            args.clip.resolve(),
            runs[name],
            args.preset,
            args.sets,
            args.variant,
        )
    equal = compare_runs(runs["old"], runs["new"])
    print("same bits" if equal else "different bits", f"(runs in {out})")
    return 0 if equal else 1


if __name__ == "__main__":
    sys.exit(main())
