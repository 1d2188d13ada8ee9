"""A text progress bar for management commands (no dependency).

On a terminal it redraws one line in place (``\\r``) whenever its text changes (the clock, at
least once a second while a job is followed); in a log file or a pipe it writes a line each
time another ~10% is done or ``LOG_EVERY_S`` have passed with news, and one at the end, so
logs stay short but never look stuck.
"""

from __future__ import annotations

import time
from typing import TextIO

from django.core.management.base import OutputWrapper

BAR_WIDTH = 30
LOG_STEP = 0.1
"""Fraction of progress between two lines when the output is not a terminal."""
LOG_EVERY_S = 15.0
"""Seconds after which a line is written anyway (not a terminal), if the text changed."""


def render_bar(fraction: float, text: str = "", width: int = BAR_WIDTH) -> str:
    """``[#########.....]  45%  text``; ``fraction`` is clamped to 0..1."""
    fraction = min(1.0, max(0.0, fraction))
    done = int(round(fraction * width))
    line = f"[{'#' * done}{'.' * (width - done)}] {int(fraction * 100):3d}%"
    return f"{line}  {text}" if text else line


class ProgressBar:
    """``update(fraction, text)`` as often as you like; ``close()`` once at the end."""

    def __init__(
        self, out: TextIO | OutputWrapper, *, tty: bool | None = None, width: int = BAR_WIDTH
    ) -> None:
        self.out = out
        self.width = width
        self.tty = bool(out.isatty()) if tty is None else tty
        self._shown = 0  # characters of the line on screen (tty)
        self._next_log = 0.0  # the fraction at which the next line is written (not a tty)
        self._last = ""  # the latest state
        self._written = ""  # the latest line written (not a tty)
        self._open = False
        self._logged_at = time.monotonic()

    def update(self, fraction: float, text: str = "") -> None:
        line = render_bar(fraction, text, self.width)
        if self.tty:
            if line != self._last:
                pad = " " * max(0, self._shown - len(line))
                self._write(f"\r{line}{pad}")
                self._shown = len(line)
                self._open = True
        elif fraction >= self._next_log or (
            line != self._written and time.monotonic() - self._logged_at >= LOG_EVERY_S
        ):
            self._write(line + "\n")
            self._written = line
            self._logged_at = time.monotonic()
            self._next_log = (int(fraction / LOG_STEP + 1e-9) + 1) * LOG_STEP
        self._last = line

    def close(self) -> None:
        """End the bar's line (a tty) or write the last state if it was not written."""
        if self.tty:
            if self._open:
                self._write("\n")
            self._shown = 0
        elif self._last != self._written:
            self._write(self._last + "\n")
            self._written = self._last
        self._open = False

    def _write(self, text: str) -> None:
        if isinstance(self.out, OutputWrapper):
            self.out.write(text, ending="")
        else:
            self.out.write(text)
        self.out.flush()
