"""Command/reply pairing on a Roboteq serial line: flush, write, read, attribute, count.

One :class:`ReplyLink` per open port. :meth:`ReplyLink.attempt` is one try of one command:

1. flush: whatever arrived since the last reply answers nothing the host asks now; it is read,
   counted in :attr:`ReplyLink.discarded_lines` and dropped (telemetry among it is noted, so the
   next flush can send ``# C`` again);
2. write the command;
3. read lines until the reply paired with it: with echo on, only after the command's own echo
   (a ``+``/``-`` before it answers an earlier command); a query by a ``NAME=`` line of its own
   name with the expected fields; ``!``/``^`` by ``+`` or ``-``. Echoes of other commands, other
   names, a ``+`` to a query: discarded and counted, never taken as the answer.

It returns the reply, or a string saying why the try failed (``timeout``, ``garbled``,
``rejected``, ``unattributed``); retrying and stopping are the driver's business. Port errors
(``OSError``, pyserial's ``SerialException``) propagate unchanged.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from hw.errors import ProtocolError
from hw.roboteq import codec

log = logging.getLogger(__name__)

Check = Callable[[tuple[int, ...]], None]


class ReplyLink:
    """Pairs replies with commands on ``port`` (``write``, ``read``, ``in_waiting``, ``reset_input_buffer``).

    Attributes:
        echo: the controller's echo state: True, False, or None while unknown (a read-only session
            learns it from the first echo it sees).
        discarded_lines: lines that answered nothing asked (stale, unsolicited, other echoes).
        rx_bytes: bytes received during the current command's tries (to tell a foreign device).
        stop_telemetry: send ``# C`` on the next flush after unsolicited values were seen.
    """

    def __init__(self, port: Any, timeout_s: float) -> None:
        self.port = port
        self.timeout_s = timeout_s
        self.echo: bool | None = None
        self.discarded_lines = 0
        self.rx_bytes = 0
        self.stop_telemetry = False
        self._telemetry_seen = False
        self._rx = b""

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def read_some(self) -> bytes:
        """What is buffered, or one byte within the port's own short timeout (b"" if nothing)."""
        data: bytes = self.port.read(max(1, int(getattr(self.port, "in_waiting", 0) or 0)))
        return data

    def flush(self) -> None:
        """Drop (and count) whatever arrived before the next command."""
        pending = int(getattr(self.port, "in_waiting", 0) or 0)
        data = self._rx + (self.port.read(pending) if pending else b"")
        self.port.reset_input_buffer()
        self._rx = b""
        complete, rest = codec.split_lines(data)
        lines = [ln for ln in complete if ln.strip()] + ([repr(rest)] if rest.strip() else [])
        if lines:
            self.discarded_lines += len(lines)
            log.debug("Roboteq: flushed %d stale line(s): %r", len(lines), lines[:5])
            self._telemetry_seen = self._telemetry_seen or any("=" in ln for ln in lines)
        if self._telemetry_seen and self.stop_telemetry:
            # values nobody asked for: telemetry started by a script or another tool; stop it again
            self._telemetry_seen = False
            self.write(b"# C" + codec.CR)

    def attempt(self, cmd: codec.Command, expected: Check | None) -> codec.Reply | str:
        """One try: flush, write ``cmd``, await its reply (a str says why the try failed)."""
        self.flush()
        self.write(cmd.encode())
        return self._await_reply(cmd, expected)

    def send_stop(self, cmds: list[codec.Command]) -> bool:
        """Write ``cmds`` at once, without pairing, and wait one deadline; True if all were acked."""
        self._rx = b""
        with contextlib.suppress(OSError):
            self.port.reset_input_buffer()
        self.write(b"".join(c.encode() for c in cmds))
        acks, deadline = 0, time.monotonic() + self.timeout_s
        while acks < len(cmds) and time.monotonic() < deadline:
            lines, self._rx = codec.split_lines(self._rx + self.read_some())
            acks += sum(1 for line in lines if line.strip() == "+")
        return acks == len(cmds)

    def _await_reply(self, cmd: codec.Command, expected: Check | None) -> codec.Reply | str:
        deadline = time.monotonic() + self.timeout_s
        echo_seen = self.echo is not True  # with echo off (or not known yet) there is nothing to wait for
        discarded: list[str] = []

        def discard(line: str) -> None:
            self.discarded_lines += 1
            self._telemetry_seen = self._telemetry_seen or "=" in line
            discarded.append(line)
            log.debug("Roboteq: discarded %r (not the answer to %s)", line, cmd.text)

        while True:
            lines, self._rx = codec.split_lines(self._rx)
            for line in lines:
                if not line.strip():
                    continue
                if codec.is_echo(line, cmd):
                    echo_seen = True
                    if self.echo is None:
                        self.echo = True
                    continue
                if line.lstrip()[:1] in ("#", *codec.KINDS):  # the echo of an earlier command
                    discard(line)
                    continue
                try:
                    reply = codec.parse_reply_line(line)
                except ProtocolError:
                    if not echo_seen:  # noise before our echo belongs to nothing we asked
                        discard(line)
                        continue
                    return f"garbled: {line!r}"
                if not echo_seen:  # before our echo: it answers an earlier command
                    discard(line)
                    continue
                if isinstance(reply, codec.Nack):
                    return "rejected: '-'"
                if cmd.expects_value:
                    if isinstance(reply, codec.Value) and reply.name == cmd.name:
                        if expected is None:  # ?FID: free text
                            return reply
                        try:
                            expected(reply.ints())
                        except ProtocolError as exc:
                            return f"garbled: {line!r} ({exc})"
                        return reply
                elif isinstance(reply, codec.Ack):
                    return reply
                discard(line)
            if time.monotonic() >= deadline:
                if discarded:
                    return f"unattributed: only {discarded!r} within {self.timeout_s} s"
                return f"timeout: no answer within {self.timeout_s} s"
            chunk = self.read_some()
            if chunk:
                self.rx_bytes += len(chunk)
                self._rx += chunk
