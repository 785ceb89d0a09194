"""A Foxglove WebSocket server for the live view (:mod:`robchair.observers.live`), with ``foxglove-sdk``.

Every topic is a channel with ``cdr`` messages and a ``ros2msg`` schema (the type's definition as
ROS 2 writes it into MCAP files), so Foxglove and Lichtblick decode them as they decode the run's bag.
A channel counts as wanted only while a client subscribes to it (``Channel.has_sinks``): without a
client nothing is built or serialised. A slow client loses the oldest messages in the server's
per-client backlog, never the loop's time; a client that subscribes to ``/tf_static`` gets the
static transforms again. The layout ``assets/foxglove/robchair_layout.json`` opens the topics in a
3D panel, a plot of v and w and a log of the safety decisions.
"""

from __future__ import annotations

import threading
from typing import Any

from robchair.observers.live import LiveSink
from robchair.platform.errors import ConfigError

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"
#: messages buffered per client before the oldest are dropped
CLIENT_BACKLOG = 256
MISSING = "the Foxglove SDK is not installed: pip install 'robchair[viz]' (foxglove-sdk)"


class FoxgloveSink(LiveSink):
    """Starts the server at once (so a port in use is an error before the run starts).

    Args:
        port: TCP port (0: any free one, see :attr:`port`).
        host: interface to bind (default localhost only).

    Raises:
        ConfigError: the SDK is missing, or the server cannot listen there (e.g. the port is in use).
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST) -> None:
        try:
            import foxglove.websocket
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.split(".")[0] == "foxglove":
                raise ConfigError(MISSING) from None
            raise
        self._fg = foxglove
        self._ctx = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._store: Any = None
        self._static_wanted = threading.Event()
        listener = _listener(foxglove.websocket.ServerListener, self._static_wanted)
        try:
            self.server = foxglove.start_server(name="robchair", host=host, port=int(port), context=self._ctx,
                                                server_listener=listener,
                                                message_backlog_size=CLIENT_BACKLOG)  # fmt: skip
        except RuntimeError as exc:
            raise ConfigError(
                f"--live-port {port}: cannot serve the live view on {host}:{port} ({exc})"
            ) from None
        self.port = int(self.server.port)
        self.url = f"ws://{'localhost' if host in ('127.0.0.1', 'localhost') else host}:{self.port}"

    def open(self, topics: dict[str, str], parents: dict[str, str], t0_ns: int, store: Any) -> None:
        self._store = store
        for topic, msgtype in topics.items():
            if topic in self._channels:
                continue
            text, _ = store.generate_msgdef(msgtype, ros_version=2)
            schema = self._fg.Schema(name=msgtype, encoding="ros2msg", data=text.encode())
            self._channels[topic] = self._fg.Channel(topic, schema=schema, message_encoding="cdr",
                                                     context=self._ctx)  # fmt: skip

    def wants(self, topic: str) -> bool:
        ch = self._channels.get(topic)
        return ch is not None and bool(ch.has_sinks())

    def active(self) -> bool:
        return any(ch.has_sinks() for ch in self._channels.values())

    def resend_static(self) -> bool:
        if self._static_wanted.is_set():
            self._static_wanted.clear()
            return True
        return False

    def send(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        data = self._store.serialize_cdr(msg, msgtype)
        self._channels[topic].log(bytes(data), log_time=max(int(stamp_ns), 0))

    def close(self) -> None:
        for ch in self._channels.values():
            ch.close()
        self.server.stop()


def _listener(protocol: type, static_wanted: threading.Event) -> Any:
    """A server listener (callbacks on the server's thread; the protocol's other callbacks do nothing): a
    new subscription to ``/tf_static`` asks for the static transforms again."""

    class Listener(protocol):  # type: ignore[misc, valid-type]
        def on_subscribe(self, client: Any, channel: Any) -> None:
            if channel.topic == "/tf_static":
                static_wanted.set()

    return Listener()
