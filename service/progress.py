"""Progress of a long benchmark on a terminal: missions done of total, rate, time left.

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
    total: int, *, unit: str = "mission", quiet: bool = False
) -> Iterator[Callable[[int], None]]:
    """A callable told how many more are done; a bar on stderr only when it is a terminal."""
    if quiet or not sys.stderr.isatty():
        yield lambda _: None
        return
    with tqdm(total=total, unit=unit, file=sys.stderr, dynamic_ncols=True, leave=False) as bar:
        yield bar.update
