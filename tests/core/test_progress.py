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


def test_a_slow_first_step_does_not_set_the_training_bar_s_eta(monkeypatch):
    """A first training sat on stage-1 step 0 (the kernels' first calls, a compile) with an ETA of
    hours: the bar starts after the first step, so its rate is that of the steps after it."""
    import time

    from m4dgs.training import stage as stage_mod

    made = {}
    real = stage_mod.progress_bar

    def spy(*a, **k):
        made["at"] = time.perf_counter()
        made["bar"] = real(*a, **k)
        return made["bar"]

    monkeypatch.setattr(stage_mod, "progress_bar", spy)

    class Slow:
        def step(self, it):
            if it == 0:
                time.sleep(0.5)
                made["first_done"] = time.perf_counter()
            return {"total": 0.0, "num_gaussians": 1}

    stage_mod.train_loop(Slow(), 6, progress=True)
    bar = made["bar"]
    assert made["at"] >= made["first_done"]
    assert bar.n == 6 and bar.total == 6  # every step counted
    assert bar.format_dict["elapsed"] < 0.4  # the slow first step is not in the rate
