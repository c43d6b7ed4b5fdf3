"""Options and small helpers shared by the command groups of `m4dgs-eval`."""

from __future__ import annotations

import click

from m4dgs.core.executor_options import executor_options

# Each command imports the modules it runs when it runs: `eval --help` and the listing commands stay
# free of torch (scoring), the trainer and the renderer stack, and tests can replace the trainer's
# entry points.

DEFAULT_OUT = "experiments"
FORMATS = {"md": "markdown", "markdown": "markdown", "latex": "latex", "csv": "csv"}


def parse_names(text):
    """A comma-separated list of names (None for an empty one: all of them)."""
    return None if not text else [s.strip() for s in text.split(",") if s.strip()]


# --------------------------------------------------------------------------------------------------
# options of the scorers (`score`, `score-frames`); --lpips-weights also of `run`, `job`, `campaign`
lpips_opt = click.option(
    "--lpips-weights",
    default=None,
    type=click.Path(exists=True, dir_okay=False),
    help="LPIPS weights file (AlexNet + linear heads, docs/metrics.md); without it LPIPS is n/a.",
)
roundtrip_opt = click.option(
    "--roundtrip",
    type=click.Choice(["none", "png", "jpeg"]),
    default="none",
    show_default=True,
    help="8-bit round trip of the LDR frames before scoring (jpeg: as the authors scored).",
)
flip_opt = click.option(
    "--flip", is_flag=True, help="Also compute HDR-FLIP on the test frames (slow)."
)


# --------------------------------------------------------------------------------------------------
out_opt = click.option(
    "--root",
    "--out",
    "out",
    default=DEFAULT_OUT,
    show_default=True,
    type=click.Path(file_okay=False),
    metavar="ROOT",
    help="Experiment root (the same as --root of `table` and `export`; --out is its older name): "
    "clips in ROOT/clips/<setting>/<scene>, runs in ROOT/runs/<suite>/<scene>/<row>, figures in "
    "ROOT/figures/<suite>. One ROOT per preset.",
)
rows_opt = click.option(
    "--rows",
    default=None,
    help="Comma-separated subset of the suite's rows (default: all of them), e.g. the full "
    "method and the calibration rows before the ablations.",
)
scenes_opt = click.option(
    "--scenes",
    default=None,
    help="Comma-separated subset of the scenes (default: all of each suite's scenes).",
)


class SeedsType(click.ParamType):
    """--seeds: N (trainer seeds 0 .. N-1) or a comma-separated list of seeds, e.g. 2,3
    (eval.experiments.runner.seed_list); an int or a list of ints."""

    name = "N|S,S,..."

    def convert(self, value, param, ctx):
        from eval.experiments.runner import seed_list

        if isinstance(value, (int, list)):
            return value
        text = str(value).strip()
        try:
            if "," in text:
                seeds = [int(v) for v in text.split(",") if v.strip()]
                seed_list(seeds)
                return seeds
            n = int(text)
            seed_list(n)
            return n
        except ValueError:
            self.fail(
                f"{value!r}: expected a count N >= 1 (seeds 0..N-1) or a comma-separated list of "
                "distinct seeds >= 0 (e.g. 2,3)",
                param,
                ctx,
            )


SEEDS = SeedsType()


def found_seeds_opt(verb: str):
    """--seeds of the commands that read run folders: seeds 0..N-1 (or the listed seeds) to
    `verb`, by default up to the largest seed with a run folder."""
    return click.option(
        "--seeds",
        default=None,
        type=SEEDS,
        help=f"Trainer seeds to {verb}: N for 0..N-1, or a list such as 2,3 (default: 0 up to the "
        "largest seed with a run folder).",
    )


preset_opt = click.option(
    "--preset",
    type=click.Choice(["tiny", "small", "paper"]),
    default="small",
    show_default=True,
    help="Clip preset AND training preset (tiny: tests and the demo).",
)
device_opt = click.option(
    "--device",
    default="auto",
    show_default=True,
    help="Training / scoring device: auto, cpu or cuda.",
)

jobs_opt = click.option(
    "--jobs",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="Local worker processes, each with cpu_count / N threads (torch's operations on one, "
    "the compiled rasterizer on all of them: the fastest split measured, docs/performance.md).",
)
no_share_opt = click.option(
    "--no-share",
    is_flag=True,
    help="Compute every trainer phase in every run. By default the runs of one clip share camera "
    "initialisation, stage 1, the V2W transform and stage 2 through ROOT/.shared wherever their "
    "configurations agree on what that phase reads (stage 2: the whole configuration and the "
    "variant, e.g. the full row of two suites; never across trainer seeds; docs/eval.md).",
)


no_retry_failed_opt = click.option(
    "--no-retry-failed",
    is_flag=True,
    help="Do not run again a job whose last attempt failed (<run>/failure.json, or, for `campaign` "
    "when the run folder is gone, the runs CSV's `failed` row): a failure that repeats is a "
    "result of its configuration, and its row stays `failed`. By default such jobs are retried.",
)


# --------------------------------------------------------------------------------------------------
runs_csv_opt = click.option(
    "--csv",
    "csv_path",
    default="results/runs.csv",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="Runs CSV to create or merge into (learned CRF curves go to <stem>-crf.csv beside it).",
)


# --csv of the commands that read the runs CSV alone (pairs, repeats)
read_csv_opt = click.option(
    "--csv",
    "csv_path",
    default="results/runs.csv",
    show_default=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Runs CSV written by `export`.",
)


# --clip of the commands that read several runs' renders (regions, error-maps)
runs_clip_opt = click.option(
    "--clip",
    "clip_dir",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder for every run (default: the 'clip' entry of each RUN/run.json); needed for "
    "a prediction folder of `score-frames`.",
)


# --------------------------------------------------------------------------------------------------
# where `suite run` and `suite campaign` run their jobs (m4dgs.core.executors; the options are
# shared with `benchgen make`, m4dgs.core.executor_options)
executor_opts = executor_options(
    where="Where the clips and jobs run: local (this machine, --jobs workers), ray (a Ray "
    "cluster: --address, or one started on this machine) or slurm (job arrays through "
    "submitit). docs/cluster.md.",
    cpus="CPU threads of one job (default: local cpu_count / --jobs; ray and slurm 2).",
    gpus="GPUs of one training job, 0 or 1, for ray and slurm (default: 1 with --device "
    "cuda, else 0); clips take none.",
)
