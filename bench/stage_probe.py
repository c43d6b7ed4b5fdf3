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
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402
import yaml  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from step_bench import copy_run_models, make_stage  # noqa: E402

from m4dgs.core.threads import use_threads  # noqa: E402
from m4dgs.training.pipeline import Trainer  # noqa: E402


def parse_overrides(text: str) -> dict:
    """'a.b=1,c.d=true' -> {'a.b': 1, 'c.d': True} (values parsed as YAML scalars)."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        if "=" not in item:
            raise SystemExit(f"override {item!r} is not KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip()] = yaml.safe_load(v)
    return out


def run_arm(
    clip: str,
    src: Path,
    overrides: dict,
    start: int,
    steps: int,
    seed: int,
    preset: str = "small",
    variant: str = "full",
) -> list:
    """The per-step records of `steps` stage-2 steps from RUN's final model under the preset, the
    variant and `overrides`."""
    tmp = Path(tempfile.mkdtemp(prefix="stage_probe_"))
    try:
        copy_run_models(src, tmp)
        tr = Trainer(clip, tmp, preset, variant, overrides, "cpu", progress=False)
        st, first = make_stage(tr, src, "stage2", start, final=True)
        torch.manual_seed(seed)
        return [st.step(it) for it in range(first, first + steps)]
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
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    a = ap.parse_args()
    use_threads(a.threads, "cpu")
    src = Path(a.run)
    if not (src / "model" / "final.pt").exists():
        ap.error(f"{src} has no model/final.pt: RUN must be a finished run")
    base = parse_overrides(a.base_overrides)
    terms = a.terms.split(",")
    print(
        f"steps {a.start}..{a.start + a.steps - 1}, windows of {a.window}; per term: window means"
    )
    for spec in a.arm:
        name, _, ov = spec.partition(":")
        ovr = {**base, **parse_overrides(ov)}
        recs = run_arm(a.clip, src, ovr, a.start, a.steps, a.seed, a.preset, a.variant)
        for t in terms:
            vals = []
            for w0 in range(0, len(recs), a.window):
                xs = [r[t] for r in recs[w0 : w0 + a.window] if t in r]
                vals.append(f"{sum(xs) / len(xs):.5f}" if xs else "-")
            print(f"{name:>16s} {t:>6s}: " + " ".join(vals))


if __name__ == "__main__":
    main()
