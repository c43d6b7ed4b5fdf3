"""The project's own errors and how the command-line tools report them.

An `M4DGSError` is a problem with the user's files, data or settings (a clip without a field, a
scene spec out of range, a run folder in use): the tools print it in one line naming the file and
the field, and exit with status 1. Anything else is a bug and keeps its traceback. Usage errors
(bad options) are click's and exit with status 2. `--debug` on any tool, or the environment
variable M4DGS_DEBUG=1, shows the traceback of a project error too.
"""

from __future__ import annotations

import os

import click


class M4DGSError(Exception):
    """An error in the user's input (files, data, settings) or environment, not in the code."""


class InputError(M4DGSError, ValueError):
    """Bad content of a file or setting; the message names the file (or option) and the field."""


class RunInUseError(M4DGSError):
    """A run folder is being written by another live process."""


class NonFiniteError(M4DGSError, FloatingPointError):
    """A loss, parameter or render became NaN or infinite."""


def debug_enabled() -> bool:
    return os.environ.get("M4DGS_DEBUG", "").strip() not in ("", "0", "false", "no")


class ReportingGroup(click.Group):
    """A click group whose commands report `M4DGSError` in one line (exit 1) instead of a
    traceback, and which adds `--debug` (traceback for every error) and `--version`."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.params.append(
            click.Option(
                ["--debug"],
                is_flag=True,
                expose_value=False,
                is_eager=True,
                callback=_set_debug,
                help="Show the full traceback of errors in your input too (or M4DGS_DEBUG=1).",
            )
        )
        self.params.append(
            click.Option(
                ["--version"],
                is_flag=True,
                expose_value=False,
                is_eager=True,
                callback=_print_version,
                help="Print the package version and exit.",
            )
        )

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except M4DGSError as e:
            if debug_enabled() or ctx.meta.get("m4dgs.debug"):
                raise
            raise click.ClickException(str(e).strip() or type(e).__name__) from None


def package_version() -> str:
    """The installed version of the mono4dgs-hdr package ("unknown" when run from a bare
    checkout that was never installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mono4dgs-hdr")
    except PackageNotFoundError:
        return "unknown"


def _print_version(ctx, param, value):
    if value and not ctx.resilient_parsing:
        click.echo(f"{ctx.info_name} (mono4dgs-hdr) {package_version()}")
        ctx.exit()


def _set_debug(ctx, param, value):
    if value:
        ctx.meta["m4dgs.debug"] = True
