"""Progress bars that suit where they are shown.

tqdm redraws at most every 0.1 s: right on a terminal, but a run piped into a log file then
writes ten carriage-return updates a second (a small training run's log grew by about a megabyte
of bar updates). `progress_bar` keeps tqdm's interval on a terminal and redraws every
`LOG_INTERVAL_S` seconds otherwise."""

from __future__ import annotations

import sys

LOG_INTERVAL_S = 30.0  # seconds between redraws when the bar's stream is not a terminal


def redraw_interval(stream=None) -> float:
    """tqdm's mininterval for a bar written to `stream` (default: sys.stderr, tqdm's stream)."""
    stream = sys.stderr if stream is None else stream
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        tty = False
    return 0.1 if tty else LOG_INTERVAL_S


def progress_bar(iterable=None, **kwargs):
    """tqdm(iterable, **kwargs) with dynamic_ncols and, unless given, the redraw interval of
    `redraw_interval` for its stream (kwargs["file"] or stderr)."""
    from tqdm import tqdm  # deferred: only the commands that show bars need it

    kwargs.setdefault("dynamic_ncols", True)
    kwargs.setdefault("mininterval", redraw_interval(kwargs.get("file")))
    return tqdm(iterable, **kwargs)
