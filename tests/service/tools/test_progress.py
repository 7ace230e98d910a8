"""Progress bars appear on a terminal only."""

from __future__ import annotations

import io
import sys

import pytest

from service.tools.progress import progress_bar


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_sees_the_count_the_rate_and_the_total(monkeypatch: pytest.MonkeyPatch) -> None:
    out = Terminal()
    monkeypatch.setattr(sys, "stderr", out)
    with progress_bar(40, desc="suite", min_interval_s=0.0) as progress:
        progress(3)
        progress(37)
    assert "40/40" in out.getvalue()
    assert "suite" in out.getvalue()


def test_without_a_total_the_count_is_shown(monkeypatch: pytest.MonkeyPatch) -> None:
    out = Terminal()
    monkeypatch.setattr(sys, "stderr", out)
    with progress_bar(None, unit="tick", desc="replay run.mcap", min_interval_s=0.0) as progress:
        progress(12)
    assert "12tick" in out.getvalue().replace(" ", "")


@pytest.mark.parametrize(("stream", "quiet"), [(io.StringIO(), False), (Terminal(), True)])
def test_a_pipe_or_json_output_sees_nothing(
    monkeypatch: pytest.MonkeyPatch, stream: io.StringIO, quiet: bool
) -> None:
    monkeypatch.setattr(sys, "stderr", stream)
    with progress_bar(5, quiet=quiet) as progress:
        progress(5)
    assert stream.getvalue() == ""
