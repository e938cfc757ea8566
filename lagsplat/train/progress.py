"""Progress of a training loop: a tqdm bar on a terminal, a plain line every ~30 s in a log.

Under Snakemake, a batch scheduler or ``nohup`` the standard error is a file,
where a tqdm bar is either silent or a stream of carriage returns; there the
loop prints one line at a fixed wall-time interval instead::

    stage1: step 300/1500 (20%), loss 0.0123, 5.1 steps/s, ETA 3m55s
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from typing import Any, TextIO

from tqdm.auto import tqdm

__all__ = ["Progress", "format_seconds"]


def format_seconds(s: float) -> str:
    """``"1h02m"``, ``"3m55s"`` or ``"42s"`` for a duration in seconds."""
    s = max(0, int(round(s)))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class Progress:
    """Iterate ``range(total)`` and report progress.

    Args:
        total: number of iterations (steps or epochs).
        desc: name printed in front (``"stage1"``).
        enabled: ``False`` prints nothing.
        unit: what one iteration is (``"step"``, ``"epoch"``).
        interval: seconds between two plain lines (no terminal).
        stream: where to write (default ``sys.stderr``); a terminal gets a
            tqdm bar, anything else the plain lines.

    Use :meth:`update` with the current loss (and other named values) inside
    the loop; the bar's postfix or the next line shows them.
    """

    def __init__(
        self,
        total: int,
        desc: str,
        enabled: bool = True,
        unit: str = "step",
        interval: float = 30.0,
        stream: TextIO | None = None,
    ) -> None:
        self.total, self.desc, self.enabled, self.unit, self.interval = int(total), desc, enabled, unit, float(interval)
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", lambda: False)
        self.tty = bool(enabled and isatty())
        self._bar = tqdm(total=self.total, desc=desc, file=self.stream, dynamic_ncols=True) if self.tty else None
        self._values: dict[str, Any] = {}
        self._t0 = self._last = time.perf_counter()
        self._done = 0

    def __iter__(self) -> Iterator[int]:
        try:
            for i in range(self.total):
                yield i
                self._done = i + 1
                if self._bar is not None:
                    self._bar.update(1)
                elif self.enabled and time.perf_counter() - self._last >= self.interval:
                    self._print_line()
            if self.enabled and self._bar is None:
                self._print_line()
        finally:
            if self._bar is not None:
                self._bar.close()

    def update(self, **values: Any) -> None:
        """Record named values (floats are shown with 4 significant digits) for the bar or the next line."""
        self._values.update(values)
        if self._bar is not None:
            self._bar.set_postfix({k: _fmt(v) for k, v in values.items()}, refresh=False)

    def line(self) -> str:
        """The plain progress line for the iterations done so far."""
        elapsed = time.perf_counter() - self._t0
        rate = self._done / elapsed if elapsed > 0 else 0.0
        pct = 100.0 * self._done / max(self.total, 1)
        parts = [f"{self.desc}: {self.unit} {self._done}/{self.total} ({pct:.0f}%)"]
        parts += [f"{k} {_fmt(v)}" for k, v in self._values.items()]
        parts.append(f"{rate:.3g} {self.unit}s/s")
        if self._done < self.total and rate > 0:
            parts.append(f"ETA {format_seconds((self.total - self._done) / rate)}")
        else:
            parts.append(f"took {format_seconds(elapsed)}")
        return ", ".join(parts)

    def _print_line(self) -> None:
        print(self.line(), file=self.stream, flush=True)
        self._last = time.perf_counter()


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)
