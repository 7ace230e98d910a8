"""Progress of a long command on a terminal (``oslim bench``, ``oslim replay``): done of total,
rate, time left.

Silent when standard error is not a terminal or the output is JSON, so logs and pipes get only
the results.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from tqdm import tqdm


@contextmanager
def progress_bar(
    total: int | None,
    *,
    unit: str = "mission",
    desc: str | None = None,
    quiet: bool = False,
    min_interval_s: float = 0.1,
) -> Iterator[Callable[[int], None]]:
    """A callable told how many more are done; a bar on stderr only when it is a terminal
    (``total`` None: a count and a rate, no time left)."""
    if quiet or not sys.stderr.isatty():
        yield lambda _: None
        return
    bar = tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, dynamic_ncols=True, leave=False,
               mininterval=min_interval_s)  # fmt: skip
    with bar:
        yield bar.update
