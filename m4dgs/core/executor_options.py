"""The command-line options that choose an executor (m4dgs.core.executors), shared by
`m4dgs-eval suite run / campaign` and `benchgen make`: --executor local|ray|slurm and the options of
each. A command declares them with `executor_options(...)` (its own words for what a task is and
what --cpus-per-job / --gpus-per-job mean there), receives them as keyword arguments named in
EXECUTOR_OPTS, and turns them into an executor with make_executor_from."""

from __future__ import annotations

from typing import Optional

import click

EXECUTOR_OPTS = (
    "executor",
    "cpus_per_job",
    "gpus_per_job",
    "address",
    "max_retries",
    "ray_dashboard",
    "ray_temp_dir",
    "slurm_folder",
    "slurm_partition",
    "slurm_time",
    "slurm_array_parallelism",
)


def executor_options(*, where: str, cpus: str, gpus: Optional[str], task: str = "job"):
    """A decorator adding --executor and the options of each executor to a click command.

    where: help of --executor (what runs where); cpus, gpus: help of --cpus-per-job and
    --gpus-per-job in the command's terms (gpus None: no --gpus-per-job, the command decides a
    task's GPUs itself); task: what one task is called in the other options' help ("job",
    "render task")."""

    def decorate(f):
        opts = [
            click.option(
                "--executor",
                type=click.Choice(["local", "ray", "slurm"]),
                default="local",
                show_default=True,
                help=where,
            ),
            click.option("--cpus-per-job", type=click.IntRange(min=1), default=None, help=cpus),
            click.option(
                "--gpus-per-job", type=click.IntRange(min=0, max=1), default=None, help=gpus
            )
            if gpus is not None
            else None,
            click.option(
                "--address",
                default=None,
                help="Ray: the cluster to connect to ('auto', or HOST:PORT of the head); without "
                "it a cluster on this machine is started for the command (127.0.0.1 only).",
            ),
            click.option(
                "--max-retries",
                default=3,
                show_default=True,
                type=click.IntRange(min=0),
                help=f"Ray: reruns of a {task} whose worker process died (a {task} that fails "
                "is not rerun).",
            ),
            click.option(
                "--ray-dashboard",
                is_flag=True,
                help="Ray, with a cluster started here: start its dashboard (127.0.0.1:8265).",
            ),
            click.option(
                "--ray-temp-dir",
                default=None,
                type=click.Path(file_okay=False),
                help="Ray, with a cluster started here: its temp dir (default: a new one, removed "
                "at the end).",
            ),
            click.option(
                "--slurm-folder",
                default=None,
                type=click.Path(file_okay=False),
                help="Slurm: folder for the array tasks' logs and submitit's files, on storage "
                "every node sees (required with --executor slurm).",
            ),
            click.option("--slurm-partition", default=None, help="Slurm: the partition."),
            click.option(
                "--slurm-time",
                default=None,
                type=click.IntRange(min=1),
                help="Slurm: time limit of one array task in minutes (default 240).",
            ),
            click.option(
                "--slurm-array-parallelism",
                default=None,
                type=click.IntRange(min=1),
                help="Slurm: at most this many array tasks at once (default: Slurm's limit).",
            ),
        ]
        for o in reversed(opts):
            if o is not None:
                f = o(f)
        return f

    return decorate


def make_executor_from(opts: dict, jobs: int, device: str):
    """The executor (m4dgs.core.executors.make_executor) of the EXECUTOR_OPTS values in `opts`,
    with `jobs` local workers and `device`; a misplaced option (e.g. --address without --executor
    ray) raises click.UsageError naming it."""
    from m4dgs.core.errors import InputError
    from m4dgs.core.executors import make_executor

    kw = {k: opts.get(k) for k in EXECUTOR_OPTS if k != "executor"}
    try:
        return make_executor(
            opts["executor"],
            jobs=jobs,
            device=device,
            dashboard=bool(kw.pop("ray_dashboard")),
            **kw,
        )
    except InputError as e:
        raise click.UsageError(str(e)) from None
