"""The project's own errors and how the command-line tools report them.

An `M4DGSError` is a problem with the user's files, data or settings (a clip without a field, a
scene spec out of range, a run folder in use): the tools print it in one line naming the file and
the field, and exit with status 1. The operating system's refusals that the user can act on
(permission denied, no space left, a file-size limit, a read-only file system, a disk quota) are
reported the same way, in one line naming the path and what to do (`os_error_line`). Anything else
is a bug and keeps its traceback. Usage errors (bad options) are click's and exit with status 2.
`--debug` on any tool, or the environment variable M4DGS_DEBUG=1, shows the traceback of a
project error too.
"""

from __future__ import annotations

import errno
import os
from typing import Optional

import click


class M4DGSError(Exception):
    """An error in the user's input (files, data, settings) or environment, not in the code."""


class InputError(M4DGSError, ValueError):
    """Bad content of a file or setting; the message names the file (or option) and the field."""


class RunInUseError(M4DGSError):
    """A run folder is being written by another live process."""


class NonFiniteError(M4DGSError, FloatingPointError):
    """A loss, parameter or render became NaN or infinite."""


# errno -> (what happened, what to do): the refusals of the operating system that are the user's
# environment, not the code (a full disk, a folder without write permission, `ulimit -f`)
OS_REFUSALS = {
    errno.EACCES: ("permission denied", "check the folder's permissions or write somewhere else"),
    errno.EPERM: ("operation not permitted", "check the folder's permissions or owner"),
    errno.ENOSPC: ("no space left on the device", "free some space or write to another disk"),
    errno.EDQUOT: ("disk quota exceeded", "free some space or write to another disk"),
    errno.EFBIG: (
        "file too large for this process's file-size limit",
        "raise the limit (`ulimit -f unlimited`) or write to another file system",
    ),
    errno.EROFS: ("read-only file system", "write to a writable folder"),
}


def os_error_line(e: BaseException) -> Optional[str]:
    """One line for an OSError the user can act on (OS_REFUSALS: permission, space, file size,
    read-only file system), naming the path when the error carries one; None for any other error
    (a bug keeps its traceback). Partial writes have no file name of their own: the shared writers
    (m4dgs.core.io.atomic_target, RunDir.log) re-raise them with the destination's."""
    if not isinstance(e, OSError) or e.errno not in OS_REFUSALS:
        return None
    what, todo = OS_REFUSALS[e.errno]
    where = f"{e.filename}: " if e.filename else ""
    if e.filename2:
        where = f"{e.filename} -> {e.filename2}: "
    return f"{where}{what} ({todo})"


def with_path(e: OSError, path) -> OSError:
    """`e` with `path` as its file name (a new OSError of the same errno and class) when it has
    none or names a temporary file; the original otherwise. For writers whose partial-write
    errors name nothing or a temporary name the user never asked for."""
    name = os.path.basename(str(e.filename)) if e.filename else ""
    if e.errno is None or (name and not name.startswith(f".{os.path.basename(str(path))}.")):
        return e
    return OSError(e.errno, e.strerror or os.strerror(e.errno), str(path))


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
            raise click.ClickException(one_line(str(e)) or type(e).__name__) from None
        except OSError as e:
            line = os_error_line(e)
            if line is None or debug_enabled() or ctx.meta.get("m4dgs.debug"):
                raise
            raise click.ClickException(line) from None


def one_line(text: str) -> str:
    """`text` with its lines joined by "; " (libraries' messages, e.g. an image reader's, can span
    several lines; the tools promise one)."""
    return "; ".join(ln.strip() for ln in str(text).splitlines() if ln.strip())


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
