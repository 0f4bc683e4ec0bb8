"""What GRT's commands print while they work, read on a terminal or in a log (``make demo | tee log``).

On a terminal: a tqdm bar and rich tables fitted to the window. In a log (the stream is not a TTY): no
carriage returns and no wrapping at 80 columns, so

* :func:`progress` gives plain lines, one every ``every_s`` seconds (10) or every 10% of the work,
  whichever comes first, and one at the end: ``red-team: 12/65 (18%), 0:14 elapsed, 0.85 cand/s, ETA 1:02``
  (the rate is the average since the bar was made; the ETA uses the rate after the first unit, which
  also loads the object, and is left out until there is one);
* :func:`console` gives a rich console as wide as its content (tables and paths are never cut).

A bar's rate clock starts when the bar is made: make it after the simulator workers are up (the
caller prints one start-up line before that), so its first ETA is not the start-up's. Its rate is the
average since then (not tqdm's smoothed recent rate), the figure a command's summary reports.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

WIDE = 240  # columns of the console in a log: tables size to their content, text is not wrapped


def is_tty(stream: TextIO | None) -> bool:
    """Whether ``stream`` is a terminal (``False`` for a pipe, a file, or a stream without ``isatty``)."""
    try:
        return bool(stream is not None and stream.isatty())
    except (AttributeError, ValueError):  # closed or not a real stream
        return False


def console(file: TextIO | None = None):
    """A rich console on ``file`` (stdout): the terminal's width on a TTY, else :data:`WIDE` columns and no
    soft wrapping of long lines (a log keeps whole paths and whole table headers)."""
    from rich.console import Console

    stream = file if file is not None else sys.stdout
    if is_tty(stream):
        return Console(file=file)
    return Console(file=file, width=WIDE, soft_wrap=True, color_system=None)


def _clock(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"


class LineProgress:
    """A progress report as plain lines (tqdm's ``update``/``set_postfix``/``close`` and a context manager).

    Args:
        total: units of work.
        desc: what is counted (the line's first word).
        unit: the unit of the rate (``cand``, ``trial``).
        initial: units already done (a resumed run): counted in done/total, not in the rate.
        file: where the lines go (stderr, where tqdm's bar would be).
        every_s: seconds between lines at the most; a line is also written at each 10% of ``total``.
    """

    def __init__(self, total: int, desc: str, unit: str = "it", initial: int = 0, file: TextIO | None = None,
                 every_s: float = 10.0):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.n = self.initial = int(initial)
        self.file = file if file is not None else sys.stderr
        self.every_s = float(every_s)
        self.start = self.last = time.perf_counter()
        self.postfix = ""
        self.closed = False
        self._first: tuple[float, int] | None = None  # (time, n) when the first unit was done
        self._next_tenth = self._tenth(self.n) + 1

    def _tenth(self, n: int) -> int:
        return (10 * n) // self.total if self.total else 10

    def rate(self) -> float:
        """Units per second since the bar was made (resumed units excluded)."""
        elapsed = time.perf_counter() - self.start
        return (self.n - self.initial) / elapsed if elapsed > 0 else 0.0

    def _steady_rate(self) -> float | None:
        """Units per second after the first one (which also loads the object into each worker), for the
        ETA; ``None`` until a second unit is done."""
        if self._first is None or self.n <= self._first[1]:
            return None
        return (self.n - self._first[1]) / max(time.perf_counter() - self._first[0], 1e-9)

    def line(self) -> str:
        """The current line: ``desc: n/total (p%), r unit/s, ETA m:ss [postfix]``."""
        done = self.n - self.initial
        rate = self.rate()
        pct = f" ({100 * self.n / self.total:.0f}%)" if self.total else ""
        text = f"{self.desc}: {self.n}/{self.total}{pct}, {_clock(time.perf_counter() - self.start)} elapsed"
        if done > 0 and rate > 0:
            text += f", {rate:.3g} {self.unit}/s"
            steady = self._steady_rate()
            if self.total and self.n < self.total and steady:
                text += f", ETA {_clock((self.total - self.n) / steady)}"
        return text + (f", {self.postfix}" if self.postfix else "")

    def _write(self) -> None:
        print(self.line(), file=self.file, flush=True)
        self.last = time.perf_counter()

    def update(self, n: int = 1) -> None:
        self.n += int(n)
        if self._first is None:
            self._first = (time.perf_counter(), self.n)
        tenth = self._tenth(self.n)
        if tenth >= self._next_tenth or time.perf_counter() - self.last >= self.every_s:
            self._next_tenth = tenth + 1
            if self.n < self.total:  # the last line is close()'s
                self._write()

    def set_postfix(self, **values: Any) -> None:
        self.postfix = " ".join(f"{k}={v}" for k, v in values.items())

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            if self.n > self.initial:
                self._write()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress(total: int, desc: str, unit: str = "it", initial: int = 0, leave: bool = True,
             file: TextIO | None = None):
    """A tqdm bar on a terminal, :class:`LineProgress` lines in a log; both report the average rate.

    Args:
        total, desc, unit, initial: as tqdm's.
        leave: keep the bar on the terminal when it closes (tqdm's ``leave``).
        file: the stream (stderr).
    """
    stream = file if file is not None else sys.stderr
    if not is_tty(stream):
        return LineProgress(total, desc, unit, initial, stream)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, initial=initial, leave=leave, file=stream, dynamic_ncols=True,
                smoothing=0)
