"""The live Foxglove view: a foxglove-sdk WebSocket server publishing what the MCAP records.

``[foxglove] listen = "host:port"`` turns it on (off when empty). It mirrors the recording
rather than being fed separately: ``Recorder(config, mirror=view)`` writes through
``view.tee(...)``, an MCAP writer that also advertises every channel it registers (same topic,
encoding and schema) and sends every message it writes (same bytes, same log time). So the live
view cannot drift from the recording's contract; it stops when the recording stops.

The server (foxglove-sdk's, in its own threads) uses a private ``foxglove.Context``, so nothing
else logged through the SDK's global context leaks into it. A client that connects late gets
messages from then on; every drawable topic is re-sent every tick. Sending never raises into
the mission: a failure is logged once and the view stops sending.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from typing import IO, TYPE_CHECKING, Any

from mcap.writer import Writer

from service.core.errors import ConfigError

if TYPE_CHECKING:
    import foxglove
    from foxglove.websocket import WebSocketServer

log = logging.getLogger(__name__)

SERVER_NAME = "oslim"


def parse_listen(listen: str) -> tuple[str, int]:
    """``host:port`` (``[v6]:port`` too) as (host, port); ConfigError naming ``foxglove.listen``."""
    host, sep, port = listen.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"foxglove.listen: expected host:port, got {listen!r}")
    return host, int(port)


class LiveView:
    """A running Foxglove WebSocket server; ``with LiveView("127.0.0.1:8765") as view: ...``.

    Port 0 lets the OS choose; ``port`` tells which one it chose.
    """

    def __init__(self, listen: str) -> None:
        self.host, self._requested_port = parse_listen(listen)
        self._context: foxglove.Context | None = None
        self._server: WebSocketServer | None = None
        self._channels: dict[str, foxglove.Channel] = {}
        self._failed = False

    @property
    def port(self) -> int:
        """The port the server listens on."""
        if self._server is None:
            raise RuntimeError("the live view is not running")
        return int(self._server.port)

    def __enter__(self) -> LiveView:
        import foxglove  # the SDK loads a native library: only when the view is on

        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=SERVER_NAME, host=self.host, port=self._requested_port, context=self._context
            )
        except Exception as exc:  # the SDK reports bind failures as a plain RuntimeError
            where = f"{self.host}:{self._requested_port}"
            raise ConfigError(f"foxglove.listen: cannot listen on {where}: {exc}") from None
        log.info("foxglove live view on ws://%s:%d", self.host, self.port)
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the server (idempotent)."""
        server, self._server = self._server, None
        for channel in self._channels.values():
            with contextlib.suppress(Exception):
                channel.close()
        self._channels.clear()
        if server is not None:
            server.stop()
            log.info("foxglove live view stopped")

    def add_channel(
        self, topic: str, message_encoding: str, schema_name: str, schema_encoding: str, schema_data: bytes
    ) -> None:
        """Advertise a channel to clients (what an MCAP channel and its schema say)."""
        import foxglove

        if self._context is None or topic in self._channels:
            return
        schema = foxglove.Schema(name=schema_name, encoding=schema_encoding, data=schema_data)
        self._channels[topic] = foxglove.Channel(
            topic, schema=schema, message_encoding=message_encoding, context=self._context
        )

    def publish(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Send one message to the clients subscribed to ``topic``; never raises."""
        channel = self._channels.get(topic)
        if channel is None or self._failed:
            return
        try:
            channel.log(data, log_time=log_time_ns)
        except Exception as exc:
            self._failed = True
            log.error("foxglove live view: sending failed, view stopped sending (%s)", exc)

    def tee(self, output: IO[bytes], **writer_options: Any) -> Writer:
        """An MCAP ``Writer`` on ``output`` that also publishes here whatever it registers and writes."""
        return _MirroredWriter(self, output, **writer_options)


@contextlib.contextmanager
def open_live_view(listen: str) -> Iterator[LiveView | None]:
    """The live view for ``foxglove.listen``: None when it is empty (the view is off)."""
    if not listen:
        yield None
        return
    with LiveView(listen) as view:
        yield view


class _MirroredWriter(Writer):
    """mcap's Writer, plus: each channel is advertised on the live view and each message sent."""

    def __init__(self, view: LiveView, output: IO[bytes], **options: Any) -> None:
        super().__init__(output, **options)
        self._view = view
        self._schema_of: dict[int, tuple[str, str, bytes]] = {}
        self._topic_of: dict[int, str] = {}

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id: int = super().register_schema(name, encoding, data)
        self._schema_of[schema_id] = (name, encoding, data)
        return schema_id

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str] | None = None
    ) -> int:
        channel_id: int = super().register_channel(topic, message_encoding, schema_id, metadata or {})
        name, encoding, data = self._schema_of[schema_id]
        self._view.add_channel(topic, message_encoding, name, encoding, data)
        self._topic_of[channel_id] = topic
        return channel_id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        super().add_message(channel_id, log_time, data, publish_time, sequence)
        self._view.publish(self._topic_of[channel_id], log_time, data)
