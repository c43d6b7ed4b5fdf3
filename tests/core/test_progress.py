"""m4dgs.core.progress: bars redraw ten times a second on a terminal, twice a minute in a log."""

import io
import time

from m4dgs.core.progress import LOG_INTERVAL_S, progress_bar, redraw_interval


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_redraw_interval_follows_the_stream():
    assert redraw_interval(_Tty()) == 0.1
    assert redraw_interval(io.StringIO()) == LOG_INTERVAL_S == 30.0
    closed = io.StringIO()
    closed.close()
    assert redraw_interval(closed) == LOG_INTERVAL_S  # isatty raises on a closed stream
    assert redraw_interval(object()) == LOG_INTERVAL_S  # no isatty at all


def test_a_bar_in_a_log_writes_far_fewer_updates():
    def updates(**kw):
        stream = io.StringIO()
        for _ in progress_bar(range(60), file=stream, desc="x", miniters=1, **kw):
            time.sleep(0.01)  # 0.6 s in all
        return stream.getvalue().count("\r")

    assert updates() <= 3  # the first and the last draw
    assert updates(mininterval=0.1) >= 4  # tqdm's own interval: a redraw every 0.1 s
    bar = progress_bar(range(3), file=_Tty())
    assert bar.mininterval == 0.1
    bar.close()
    bar = progress_bar(range(3), file=io.StringIO(), mininterval=5.0)  # an explicit value wins
    assert bar.mininterval == 5.0
    bar.close()
