"""Logging with ``rank/size`` on every line (non-root ranks log warnings only) and one
progress bar on rank 0."""
from __future__ import annotations

import logging
import sys
import time


def setup_logging(comm, verbose: bool = False) -> logging.Logger:
    """Configure the ``parsph`` logger for this rank and return it."""
    logger = logging.getLogger("parsph")
    logger.handlers.clear()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(
        f"%(asctime)s {comm.rank}/{comm.size} %(levelname)s %(message)s", "%H:%M:%S"))
    logger.addHandler(handler)
    if comm.rank == 0:
        logger.setLevel(logging.DEBUG if verbose else logging.INFO)
    else:
        logger.setLevel(logging.WARNING)
    logger.propagate = False
    return logger


def _clock(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "--:--"
    seconds = int(seconds)
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h:d}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


class Progress:
    """One progress line on rank 0: simulated time, steps/s and ETA.

    On a terminal the line redraws in place; otherwise (batch jobs, CI) a line is printed
    at every tenth of the run so that logs stay short.
    """

    def __init__(self, end_time: float, enabled: bool, stream=None):
        self.end_time = end_time
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.perf_counter()
        self.next_tenth = 0.1
        self.last_draw = 0.0

    def update(self, t: float, step: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        frac = min(t / self.end_time, 1.0) if self.end_time > 0 else 1.0
        if self.tty and now - self.last_draw < 0.2 and frac < 1.0:
            return
        if not self.tty and frac < self.next_tenth and frac < 1.0:
            return
        elapsed = now - self.start
        rate = step / elapsed if elapsed > 0 else 0.0
        eta = elapsed * (1.0 - frac) / frac if frac > 0 else float("inf")
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        line = (f"[{bar}] t = {t:.4g}/{self.end_time:.4g} s  step {step}  "
                f"{rate:.1f} steps/s  ETA {_clock(eta)}")
        if self.tty:
            self.stream.write("\r" + line)
        else:
            self.stream.write(line + "\n")
            while self.next_tenth <= frac:
                self.next_tenth += 0.1
        self.stream.flush()
        self.last_draw = now

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
