"""A minimal client of the Foxglove WebSocket protocol (the spec of foxglove/ws-protocol, v1), for tests:
receives ``serverInfo`` and ``advertise``, subscribes to every advertised channel and decodes the binary
message-data frames (opcode 0x01: subscription id u32, log time u64, payload) with the ROS 2 decoder of
``mcap-ros2-support`` built from the advertised ``ros2msg`` schema text."""

from __future__ import annotations

import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

#: the SDK's name of the v1 protocol (foxglove-sdk >= 0.x; identical to ``foxglove.websocket.v1``)
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
#: subscribe once no channel was advertised for this long, s (as a viewer does after drawing its topic
#: list; a subscription sent the instant a channel is advertised can reach the server before it knows
#: the channel, and is then refused: "unknown channel")
SUBSCRIBE_AFTER_S = 0.1


@dataclass
class Received:
    server_info: dict[str, Any] | None = None
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # channel id -> advertised channel
    messages: dict[str, list[Any]] = field(default_factory=dict)  # topic -> decoded messages (at the end)
    raw: dict[str, list[bytes]] = field(default_factory=dict)  # topic -> CDR payloads as received
    frames: int = 0


def connect_when_up(url: str, deadline_s: float, alive: Any = None) -> Any:
    """A connection to ``url``, retried until it is accepted or ``deadline_s`` (monotonic) passes or
    ``alive()`` turns False."""
    while True:
        try:
            return connect(url, subprotocols=SUBPROTOCOLS, open_timeout=5, max_size=None)  # type: ignore[arg-type]
        except (OSError, TimeoutError):
            if time.monotonic() > deadline_s or (alive is not None and not alive()):
                raise
            time.sleep(0.05)


def listen(ws: Any, deadline_s: float, done: Any, out: Received | None = None) -> Received:
    """Subscribe to every channel as it is advertised and keep what arrives, until ``done(out)`` is
    True, the server closes the connection or ``deadline_s`` (monotonic) passes; then decode it (not
    while receiving: a slow client loses the oldest messages in the server's backlog)."""
    from mcap_ros2._dynamic import generate_dynamic

    out = out or Received()
    decoders: dict[int, Any] = {}  # subscription id -> (topic, decoder)
    pending: list[dict[str, int]] = []
    last_advertise = 0.0
    next_sub = 1
    while not done(out) and time.monotonic() < deadline_s:
        if pending and time.monotonic() - last_advertise > SUBSCRIBE_AFTER_S:
            ws.send(json.dumps({"op": "subscribe", "subscriptions": pending}))
            pending = []
        try:
            raw = ws.recv(timeout=0.05)
        except TimeoutError:
            continue
        except ConnectionClosed:
            break
        if isinstance(raw, str):
            msg = json.loads(raw)
            if msg["op"] == "serverInfo":
                out.server_info = msg
            elif msg["op"] == "advertise":
                last_advertise = time.monotonic()
                for ch in msg["channels"]:
                    out.channels[ch["id"]] = ch
                    decode = generate_dynamic(ch["schemaName"], ch["schema"])[ch["schemaName"]]
                    decoders[next_sub] = (ch["topic"], decode)
                    pending.append({"id": next_sub, "channelId": ch["id"]})
                    next_sub += 1
            continue
        if raw[0] != MESSAGE_DATA:
            continue
        sub_id, _log_time = struct.unpack_from("<IQ", raw, 1)
        out.raw.setdefault(decoders[sub_id][0], []).append(raw[13:])
        out.frames += 1
    by_topic = {topic: decode for topic, decode in decoders.values()}
    out.messages = {topic: [by_topic[topic](p) for p in payloads] for topic, payloads in out.raw.items()}
    return out
