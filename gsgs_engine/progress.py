"""Progress reporting for long commands: a bar on a terminal, lines in a log, progress.jsonl always.

On a terminal (stderr is a tty) the bar redraws in place with \\r; otherwise a line is printed
about every 10 %. When a job folder is given, events go to its progress.jsonl through
Job.emit (throttled, first and last step always written) so the add-on can follow along.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO


def format_seconds(s: float | None) -> str:
    if s is None or s != s or s == float("inf"):
        return "?"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m:02d}:{sec:02d}"


class Progress:
    def __init__(self, phase: str, total: int, job=None, stream: TextIO | None = None, start_step: int = 0,
                 emit_interval_s: float = 0.5, bar_width: int = 24, clock: Callable[[], float] = time.monotonic):
        self.phase = phase
        self.total = max(int(total), 0)
        self.job = job
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start_step = int(start_step)
        self._clock = clock
        self.start_time = clock()
        self._first_done: tuple[int, float] | None = None  # (step, time) of the first update after the start
        self.emit_interval_s = emit_interval_s
        self.bar_width = bar_width
        self._last_emit = -1e9
        self._last_draw = -1e9
        self._last_decile = -1 if start_step == 0 else int(10 * start_step / max(self.total, 1))
        self._open_line = False
        self._step = int(start_step)

    def eta(self, step: int) -> float | None:
        """Seconds left at `step`, at the pace since the first update after the start; None before a second one.

        The first step carries one-off work that later steps do not: a kernel compiled on first use (gsplat's CUDA
        build took 81 s of an H200 run's first step, the steps after it ~0.02 s: counted in, the estimate read 22 hours
        after that step and 12 minutes at step 100 of 1000, with 20 s left), the first allocations, the caches.
        """
        if self._first_done is None or step <= self._first_done[0]:
            return None
        rate = (self._clock() - self._first_done[1]) / (step - self._first_done[0])
        return rate * max(self.total - step, 0)

    def update(self, step: int, losses: dict | None = None, message: str = "", force: bool = False, **extra) -> None:
        now = self._clock()
        if self._first_done is None and step > self.start_step:
            self._first_done = (int(step), now)
        self._step = int(step)
        eta = self.eta(step)
        last = step >= self.total
        if self.job is not None and (force or last or step == self.start_step + 1
                                     or now - self._last_emit >= self.emit_interval_s):
            self.job.emit(self.phase, step, self.total, losses=losses, eta_s=eta, message=message, **extra)
            self._last_emit = now
        text = self._text(step, losses, eta, message)
        if self.tty:
            if force or last or now - self._last_draw >= 0.1:
                self.stream.write("\r" + text + "\x1b[K")
                self.stream.flush()
                self._open_line = True
                self._last_draw = now
        else:
            decile = int(10 * step / max(self.total, 1))
            if force or decile > self._last_decile:
                self._last_decile = decile
                self.stream.write(text + "\n")
                self.stream.flush()

    def _text(self, step: int, losses: dict | None, eta: float | None, message: str) -> str:
        frac = min(max(step / max(self.total, 1), 0.0), 1.0)
        filled = int(round(frac * self.bar_width))
        bar = "#" * filled + "-" * (self.bar_width - filled)
        loss = ""
        if losses:
            main = losses.get("loss", next(iter(losses.values())))
            loss = f" loss {main:.4f}" if isinstance(main, (int, float)) else ""
        tail = f" {message}" if message else ""
        return (f"{self.phase} [{bar}] {step}/{self.total} {100 * frac:5.1f}%{loss} "
                f"elapsed {format_seconds(self._clock() - self.start_time)} eta {format_seconds(eta)}{tail}")

    def message(self, text: str) -> None:
        """A one-off line (keeps the bar intact on a terminal) and a progress event."""
        self.close()
        self.stream.write(text + "\n")
        self.stream.flush()
        if self.job is not None:
            self.job.emit(self.phase, self._step, self.total, message=text)

    def close(self) -> None:
        if self._open_line:
            self.stream.write("\n")
            self.stream.flush()
            self._open_line = False
