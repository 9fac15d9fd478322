"""The progress protocol and a minimal progress bar on stderr.

Every long computation of the project reports through one callback signature,
``progress(done, total, label="")``: ``done`` of ``total`` units finished (0 <= done <= total:
frequencies of a sweep, samples of a time history, candidates of the fit's order search,
cells of an ensemble), ``label`` saying what (a frequency, a stage, a cell). The lower packages
(soil_impedance, structure) call it without importing this module.
"""
from __future__ import annotations

import sys
import time
from typing import Protocol


class ProgressCallback(Protocol):
    """``progress(done, total, label="")``: done of total units finished, label says what."""

    def __call__(self, done: int, total: int, label: str = "") -> None: ...


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


def labelled_bars(title: str) -> ProgressCallback:
    """A callback that prints one bar per label: ``title`` with ``{label}`` in it is the bar's
    title for each label (the fit's stages, the routes of a run)."""
    bars = {}

    def progress(done, total, label=""):
        if label not in bars:
            bars[label] = Progress(title.format(label=label))
        bars[label](done, total)
    return progress
