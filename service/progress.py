"""A one-line progress report on a terminal for long commands (``oslim replay`` of a long run).

Quiet unless the stream is a terminal: piped output, log files and ``--json`` consumers see
nothing. The line is rewritten in place (carriage return) at most every ``interval_s`` and
erased when done, so the command's own output follows on a clean line.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class TerminalProgress:
    """``progress.update(n)`` when ``n`` more units are done (as tqdm's ``update``, so a tqdm bar
    can stand in for it); ``progress.close()`` at the end."""

    def __init__(
        self,
        label: str,
        unit: str,
        *,
        stream: TextIO | None = None,
        enabled: bool = True,
        interval_s: float = 0.2,
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled and self.stream.isatty()
        self.label = label
        self.unit = unit
        self.interval_s = interval_s
        self._started = time.monotonic()
        self._shown = self._started  # a command done within interval_s shows nothing
        self._width = 0
        self.count = 0

    def update(self, n: int = 1) -> None:
        """Count ``n`` more units done; show the total (at most one write per ``interval_s``)."""
        self.count += n
        now = time.monotonic()
        if not self.enabled or now - self._shown < self.interval_s:
            return
        self._shown = now
        line = f"{self.label}: {self.count} {self.unit}, {now - self._started:.0f} s"
        self.stream.write("\r" + line.ljust(self._width))
        self.stream.flush()
        self._width = len(line)

    def close(self) -> None:
        """Erase the line (if one was written)."""
        if self.enabled and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0
