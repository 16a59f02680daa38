"""Progress of a long call (an ensemble, a periodic-orbit continuation, a verification): how much is
done, how long it has taken, and an estimate of what is left.

`Progress(total, what, report)`: `report` is None (the default: one line on stderr every
`interval` seconds or a tenth of the time elapsed, whichever is longer, once the estimated total
exceeds `quiet_below` seconds, so short calls print nothing), False (silent), or a callable
`report(done, total, elapsed, remaining)` called after every `update` (remaining in seconds, None
before the first unit is done). Thread-safe: workers of one call may update it.

No sympy and no numba here.
"""
from __future__ import annotations

import sys
import threading
import time

__all__ = ["Progress", "format_seconds", "check_report"]


def format_seconds(s: float) -> str:
    if s < 90:
        return f"{s:.0f} s"
    if s < 5400:
        return f"{s / 60:.0f} min"
    if s < 2 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def check_report(report, field: str = "progress"):
    """None, False, True (= None) or a callable; ValueError naming `field` otherwise."""
    if report is None or report is True:
        return None
    if report is False or callable(report):
        return report
    raise ValueError(f"{field}: must be true, false or a callable f(done, total, elapsed, remaining) "
                     f"(got {type(report).__name__})")


class Progress:
    def __init__(self, total: int, what: str, report=None, *, quiet_below: float = 10.0, interval: float = 10.0,
                 stream=None):
        self.total, self.what = int(total), what
        self.report = check_report(report)
        self.quiet_below, self.interval = float(quiet_below), float(interval)
        self.stream = stream
        self.done = 0
        self.t0 = time.perf_counter()
        self._last = self.t0
        self._lock = threading.Lock()
        self.lines = 0   # lines written to the stream

    def remaining(self, elapsed: float) -> float | None:
        if self.done <= 0:
            return None
        return elapsed * (self.total - self.done) / self.done

    def update(self, units: int = 1) -> None:
        with self._lock:
            self.done += int(units)
            now = time.perf_counter()
            elapsed = now - self.t0
            rem = self.remaining(elapsed)
            if self.report is False:
                return
            if self.report is not None:
                self.report(self.done, self.total, elapsed, rem)
                return
            finished = self.done >= self.total and self.lines > 0   # a call that said its progress says its end
            if rem is None or elapsed + rem < self.quiet_below or (
                    not finished and now - self._last < max(self.interval, 0.1 * elapsed)):
                return
            self._last = now
            self._say(elapsed, rem)

    def _say(self, elapsed: float, rem: float) -> None:
        pct = 100.0 * self.done / max(self.total, 1)
        line = (f"{self.what}: {self.done:,} of {self.total:,} ({pct:.1f} %) in {format_seconds(elapsed)}, "
                f"about {format_seconds(rem)} left")
        stream = self.stream or sys.stderr
        try:
            print(line, file=stream, flush=True)
            self.lines += 1
        except (OSError, ValueError):   # a closed or full stderr: progress is not worth a failure
            pass
