"""Progress lines appear on a terminal only."""

import io

from service.progress import TerminalProgress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_sees_the_count_and_a_clean_line_at_the_end() -> None:
    out = Terminal()
    progress = TerminalProgress("replay run.mcap", "ticks", stream=out, interval_s=0.0)
    progress.update(3)
    progress.update(37)
    assert "replay run.mcap: 40 ticks" in out.getvalue()
    progress.close()
    assert out.getvalue().endswith("\r")


def test_a_pipe_or_json_output_sees_nothing() -> None:
    for stream, enabled in ((io.StringIO(), True), (Terminal(), False)):
        progress = TerminalProgress("replay", "ticks", stream=stream, enabled=enabled, interval_s=0.0)
        progress.update(5)
        progress.close()
        assert stream.getvalue() == ""
