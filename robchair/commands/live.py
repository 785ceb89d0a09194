"""The live-view options of ``robchair sim`` and ``robchair run``: ``--live`` (Foxglove WebSocket) and
``--rerun`` (a Rerun viewer), see :mod:`robchair.observers.live`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

DEFAULT_PORT = 8765  # robchair.viz.foxglove_live.DEFAULT_PORT, without importing the SDK for --help


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--live``, ``--live-port``, ``--rerun``, ``--rerun-url`` and ``--rerun-serve`` to ``p``."""
    g = p.add_argument_group("watching the run live")
    g.add_argument(
        "--live",
        action="store_true",
        help="serve the run over a Foxglove WebSocket on localhost while it runs (Foxglove, Lichtblick: "
        "open ws://localhost:PORT and load assets/foxglove/robchair_layout.json)",
    )
    g.add_argument(
        "--live-port",
        type=int,
        default=DEFAULT_PORT,
        help=f"port of --live (default {DEFAULT_PORT}; 0: any free port, printed on stderr)",
    )
    g.add_argument(
        "--rerun",
        action="store_true",
        help="stream the run to a running Rerun viewer while it runs (start `rerun` first)",
    )
    g.add_argument("--rerun-url", default=None, help="the viewer's gRPC address (default: the Rerun SDK's)")
    g.add_argument(
        "--rerun-serve",
        action="store_true",
        help="with --rerun: serve the stream for viewers to connect to instead of connecting to one",
    )


@contextmanager
def live_observers(args: argparse.Namespace, recording_id: str | None = None) -> Iterator[list[Any]]:
    """The live observer the options ask for (an empty list without them), its server already listening.

    Raises:
        ConfigError: the port is not a port, is in use, or the SDK is missing (before anything runs).
        RunFolderError: ``--rerun`` without the Rerun SDK.
    """
    from robchair.platform.config import ConfigSource

    live = bool(getattr(args, "live", False))
    rerun = bool(getattr(args, "rerun", False))
    if not (live or rerun):
        yield []
        return
    from robchair.observers.live import LiveObserver, LiveSink

    sinks: list[LiveSink] = []
    observer = LiveObserver(sinks)
    try:
        if live:
            if not 0 <= args.live_port < 65536:
                raise ConfigSource().invalid(
                    "--live-port", args.live_port, "a TCP port 0-65535 (0: any free)"
                )
            from robchair.viz.foxglove_live import FoxgloveSink

            fox = FoxgloveSink(args.live_port)
            sinks.append(fox)
            print(f"live view: {fox.url} (Foxglove / Lichtblick)", file=sys.stderr)
        if rerun:
            from robchair.viz.rerun_live import RerunSink

            rr = RerunSink(args.rerun_url, serve=args.rerun_serve, recording_id=recording_id)
            sinks.append(rr)
            where = rr.url or "the Rerun viewer at the SDK's default address"
            print(f"rerun: {'serving at ' if args.rerun_serve else 'streaming to '}{where}", file=sys.stderr)
        observer.sinks = sinks
        yield [observer]
    finally:
        observer.sinks = sinks
        observer.close()
