"""Start-up errors of `oslim serve`: one message naming the problem, exit 2, nothing left behind."""

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from service.tools.sim import free_port


def serve(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    base = [
        "--set", f'mavlink.url="udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}"',
        "--set", "zenoh.multicast_scouting=false",
        "--set", f'zenoh.listen=["tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]',
        "--set", f'recorder.dir="{tmp_path / "runs"}"',
    ]  # fmt: skip
    return subprocess.run(
        [sys.executable, "-m", "service.cli", "serve", *base, *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        check=False,
    )


def only_error(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("oslim serve: ")]
    assert len(errors) == 1, result.stderr
    return errors[0]


def no_run_files(tmp_path: Path) -> bool:
    runs = tmp_path / "runs"
    return not runs.exists() or not any(runs.iterdir())


@pytest.mark.parametrize(
    ("config_text", "expected"),
    [
        (None, r"no such configuration file"),
        ("[area\ncolumns = 3", r"not valid TOML"),
        ("[area]\ncolumns = -3\n", r"area\.columns: Input should be greater than 0"),
        ("[mavlink]\nsigning_key_file = 'absent.key'\n", r"mavlink\.signing_key_file: cannot read"),
    ],
)
def test_bad_configuration(tmp_path: Path, config_text: str | None, expected: str) -> None:
    path = tmp_path / "oslim.toml"
    if config_text is not None:
        path.write_text(config_text.replace("absent.key", str(tmp_path / "absent.key")))
    line = only_error(serve(tmp_path, "--config", str(path)))
    assert str(path) in line or "signing" in line
    assert re.search(expected, line), line
    assert no_run_files(tmp_path)


def test_malformed_signing_key(tmp_path: Path) -> None:
    key = tmp_path / "short.key"
    key.write_bytes(b"0123456789")
    line = only_error(serve(tmp_path, "--set", f'mavlink.signing_key_file="{key}"'))
    assert "mavlink.signing_key_file" in line
    assert "32 raw bytes" in line


def test_absent_serial_device(tmp_path: Path) -> None:
    line = only_error(serve(tmp_path, "--set", 'mavlink.url="/dev/ttyNONEXISTENT,57600"'))
    assert "/dev/ttyNONEXISTENT" in line
    assert "No such file" in line
    assert no_run_files(tmp_path)  # the recorder opens last: no empty run file


def test_mavlink_port_in_use(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        line = only_error(serve(tmp_path, "--set", f'mavlink.url="udpin:127.0.0.1:{port}"'))
    assert "cannot open MAVLink connection" in line
    assert no_run_files(tmp_path)


def test_unwritable_recorder_dir(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")  # works as root too, unlike chmod
    line = only_error(serve(tmp_path, "--set", f'recorder.dir="{blocker / "runs"}"'))
    assert "recorder.dir" in line
    assert str(blocker) in line


def test_unwritable_snapshot_dir(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    line = only_error(serve(tmp_path, "--set", f'service.snapshot_path="{blocker / "s.npz"}"'))
    assert "service.snapshot_path" in line
    assert no_run_files(tmp_path)
