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

import contextlib
import sys
import threading
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
        self._lock = threading.Lock()
        self._last_emit = self._t0  # wall time of the last line (the heartbeat fills silences)
        self._last_text = "working"
        try:
            self._tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self._tty = False

    def _emit(self, text: str, *, transient: bool = False, remember: bool = True) -> None:
        if not self.enabled:
            return
        line = f"{self.label}: {text}"
        with self._lock:
            if remember:
                self._last_text = text.rsplit(" (", 1)[0] if text.endswith(" s)") else text
            self._last_emit = self._clock()
            if self._tty and transient:
                self.stream.write("\r\x1b[K" + line)
                self._open_line = True
            else:
                if self._open_line:
                    self.stream.write("\r\x1b[K")
                    self._open_line = False
                self.stream.write(line + "\n")
            self.stream.flush()

    @contextlib.contextmanager
    def heartbeat(self, every_s: float = 2.0):
        """Within the block, a line whenever ``every_s`` seconds passed without one: the last message
        and the time so far (a background thread; stopped when the block ends, also on an error).
        For long calls that report nothing themselves (a fit, a linearisation grid)."""
        if not self.enabled or every_s <= 0:
            yield self
            return
        stop = threading.Event()

        def beat():
            while not stop.wait(min(0.25, every_s / 4)):
                if self._clock() - self._last_emit >= every_s:
                    self._emit(f"{self._last_text} ... ({self.elapsed:.1f} s)", transient=True, remember=False)

        thread = threading.Thread(target=beat, name=f"{self.label} heartbeat", daemon=True)
        thread.start()
        try:
            yield self
        finally:
            stop.set()
            thread.join()

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

    def __call__(self, text: str) -> None:
        """``progress(text)``: a phase; so a :class:`Progress` serves where a message callback is expected."""
        self.phase(text)

    def fit_callback(self, every_s: float = 2.0):
        """A ``callback(nfev, cost, elapsed_s)`` for long fits: one line at most every ``every_s`` seconds
        (None when disabled, so that the fit skips the calls)."""
        if not self.enabled:
            return None
        last = [-float("inf")]

        def callback(nfev: int, cost: float, elapsed: float) -> None:
            now = self._clock()
            if now - last[0] >= every_s:
                last[0] = now
                self._emit(f"{nfev} evaluations, best cost {cost:.6g}, {elapsed:.1f} s")

        return callback

    def done(self) -> None:
        """Close the progress output with the total time."""
        self._emit(f"done in {self.elapsed:.1f} s")
