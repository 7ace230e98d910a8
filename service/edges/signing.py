"""MAVLink 2 message signing: the key file and the pymavlink set-up, shared by service and stub.

A signing key is 32 bytes (MAVLink 2 signing spec). The file holds them raw, or as 64 hex
digits (what ``openssl rand -hex 32`` prints). With a key set, pymavlink signs every message
sent and rejects, as BAD_DATA, every message that is unsigned, signed with another key, or
carries a timestamp not newer than the last one seen on its (link, system, component) stream
(replay protection). Its counters say how many were rejected and why (``SigningCounters``).
"""

from __future__ import annotations

import logging
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from service.core.errors import ConfigError

log = logging.getLogger(__name__)

KEY_BYTES = 32
_SIGNING_EPOCH_S = 1_420_070_400
"""MAVLink signing timestamps count 10 us units since 2015-01-01 00:00 UTC."""


def load_signing_key(path: str | Path, key_name: str = "mavlink.signing_key_file") -> bytes:
    """The 32-byte key in ``path``; ConfigError naming ``key_name`` when missing or malformed."""
    file = Path(path)
    try:
        raw = file.read_bytes()
        mode = file.stat().st_mode
    except OSError as exc:
        raise ConfigError(f"{key_name}: cannot read {file}: {exc.strerror or exc}") from None
    if len(raw) != KEY_BYTES:
        text = raw.strip()
        try:
            raw = bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            raw = b""
        if len(raw) != KEY_BYTES:
            raise ConfigError(
                f"{key_name}: {file} must hold {KEY_BYTES} raw bytes or {2 * KEY_BYTES} hex digits"
            )
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        log.warning("%s: %s is accessible to other users; chmod 600 it", key_name, file)
    return raw


def signing_timestamp(now_s: float | None = None) -> int:
    """The current MAVLink signing timestamp (10 us units since 2015)."""
    now = time.time() if now_s is None else now_s
    return int(max(now - _SIGNING_EPOCH_S, 0.0) * 100_000)


def _reject_unsigned(_mav: Any, _msg_id: int) -> bool:
    # a callback that refuses, rather than none, so that pymavlink counts the refusals
    return False


def enable_signing(conn: Any, key: bytes, link_id: int) -> None:
    """Sign everything ``conn`` sends; reject unsigned and wrongly signed input."""
    if len(key) != KEY_BYTES:
        raise ConfigError(f"a MAVLink signing key has {KEY_BYTES} bytes, got {len(key)}")
    conn.setup_signing(
        key,
        sign_outgoing=True,
        allow_unsigned_callback=_reject_unsigned,
        initial_timestamp=signing_timestamp(),
        link_id=link_id,
    )


@dataclass(frozen=True)
class SigningCounters:
    """pymavlink's signing counters for one connection."""

    good: int = 0
    """Messages with a valid signature."""
    bad_signature: int = 0
    """Signed with another key, or a replayed / too old timestamp."""
    unsigned: int = 0
    """Messages without a signature (rejected)."""

    @classmethod
    def of(cls, conn: Any) -> SigningCounters:
        signing = conn.mav.signing
        rejected = int(signing.reject_count)
        bad = int(signing.badsig_count)
        # every bad signature is also passed to the (refusing) callback, so counted as a reject
        return cls(good=int(signing.goodsig_count), bad_signature=bad, unsigned=max(rejected - bad, 0))
