"""A dependency-free progress bar on stderr, usable as a `progress(done, total)` callback."""
from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Redraws one line on a terminal, and draws nothing elsewhere: a CI log or a file gains
    nothing from a bar (its lines would outnumber the results for jobs of a tenth of a second).

    Parameters
    ----------
    label: the text before the bar.
    stream: where it is drawn; None: sys.stderr.
    enabled: False: it draws nothing (--quiet).
    """

    WIDTH = 30

    def __init__(self, label: str, stream: TextIO | None = None, enabled: bool = True) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = enabled and _is_terminal(self.stream)
        self.started = time.perf_counter()
        self._drawn = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        fraction = min(max(done / total, 0.0), 1.0)
        filled = int(round(fraction * self.WIDTH))
        bar = '#' * filled + '.' * (self.WIDTH - filled)
        elapsed = time.perf_counter() - self.started
        self.stream.write(f'\r{self.label} [{bar}] {100 * fraction:5.1f}% {done}/{total} '
                          f'{elapsed:6.1f}s')
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        """End the bar's line."""
        if self.enabled and self._drawn:
            self.stream.write('\n')
            self.stream.flush()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False
