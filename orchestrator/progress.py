"""A minimal progress bar on stderr (silent when stderr is not a terminal unless forced)."""
from __future__ import annotations

import sys
import time


class Progress:
    """Callable ``progress(done, total, label="")`` printing a bar on stderr.

    On a terminal the bar redraws in place; otherwise a line is printed every 10 %.
    ``quiet=True`` prints nothing (for --json runs whose stdout is read by scripts:
    the bar goes to stderr anyway, so quiet is only needed to keep logs short).
    """

    def __init__(self, title: str, quiet: bool = False, stream=None):
        self.title, self.quiet = title, quiet
        self.stream = stream or sys.stderr
        self.t0 = time.perf_counter()
        self._last_decile = -1

    def __call__(self, done: int, total: int, label: str = "") -> None:
        if self.quiet or total <= 0:
            return
        frac = min(1.0, done / total)
        elapsed = time.perf_counter() - self.t0
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        tty = getattr(self.stream, "isatty", lambda: False)()
        if tty:
            bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
            end = "\n" if done >= total else ""
            self.stream.write(f"\r{self.title} [{bar}] {done}/{total} {elapsed:6.1f}s eta {eta:5.1f}s {label}{end}")
        else:
            decile = int(10 * frac)
            if decile == self._last_decile:
                return
            self._last_decile = decile
            self.stream.write(f"{self.title}: {100 * frac:3.0f}% ({done}/{total}) {elapsed:.1f}s {label}\n")
        self.stream.flush()


def frequency_bar(bar):
    """Adapt a bar to the sweeps' callback ``progress(done, total, freq_hz)``."""
    return lambda done, total, f_hz: bar(done, total, f"{f_hz:.3g} Hz")


def step_bar(bar):
    """Adapt a bar to the steppers' callback ``progress(k, nt)`` (k from 1 to nt - 1)."""
    return lambda k, nt: bar(k + 1, nt)


def stage_bar(title: str):
    """A callback ``progress(stage, done, total)`` (the rational fit's) printing one bar per stage."""
    bars = {}

    def progress(stage, done, total):
        if stage not in bars:
            bars[stage] = Progress(f"{title}: {stage}")
        bars[stage](done, total)
    return progress
