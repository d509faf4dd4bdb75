"""Progress lines on stderr for long commands (no dependency).

:class:`Progress` prints one line per phase or step to a stream (stderr by
default): plain lines when the stream is not a terminal (logs, pipes, CI), a
line rewritten in place when it is.  ``enabled=False`` (``thsa --quiet``)
prints nothing.  Library code receives a :class:`Progress` (or None) as an
argument; nothing here is global.

Examples
--------
>>> import io
>>> buf = io.StringIO()
>>> p = Progress("thsa demo", stream=buf, clock=lambda: 0.0)
>>> p.phase("reading the run")
>>> p.step(1, 2, "segment 1")
>>> p.done()
>>> print(buf.getvalue().strip())
thsa demo: reading the run (0.0 s)
thsa demo: 1/2 segment 1 (0.0 s)
thsa demo: done in 0.0 s
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Phase and step messages of one command.

    Parameters
    ----------
    label : str
        Prefix of every line (the command).
    stream : text stream, optional
        Default ``sys.stderr``.
    enabled : bool
        False prints nothing.
    min_interval : float
        Steps closer than this [s] to the previous line are not printed
        (the last step always is).
    clock : callable
        Time source [s] (tests pass a fixed one).
    """

    def __init__(self, label: str, *, stream: TextIO | None = None, enabled: bool = True,
                 min_interval: float = 0.5, clock: Callable[[], float] = time.perf_counter):
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.min_interval = min_interval
        self._clock = clock
        self._t0 = clock()
        self._last = -float("inf")
        self._open_line = False
        try:
            self._tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self._tty = False

    def _emit(self, text: str, *, transient: bool = False) -> None:
        if not self.enabled:
            return
        line = f"{self.label}: {text}"
        if self._tty and transient:
            self.stream.write("\r\x1b[K" + line)
            self._open_line = True
        else:
            if self._open_line:
                self.stream.write("\r\x1b[K")
                self._open_line = False
            self.stream.write(line + "\n")
        self.stream.flush()

    @property
    def elapsed(self) -> float:
        """Seconds since the start."""
        return self._clock() - self._t0

    def phase(self, text: str) -> None:
        """Announce the next phase of the command."""
        self._emit(f"{text} ({self.elapsed:.1f} s)")

    def step(self, i: int, n: int, text: str = "") -> None:
        """Step ``i`` of ``n`` (1-based) in the current phase."""
        now = self._clock()
        if i < n and now - self._last < self.min_interval:
            return
        self._last = now
        self._emit(f"{i}/{n}{' ' + text if text else ''} ({now - self._t0:.1f} s)", transient=i < n)

    def done(self) -> None:
        """Close the progress output with the total time."""
        self._emit(f"done in {self.elapsed:.1f} s")
