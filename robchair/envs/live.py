"""The navigation environment's ``render_mode="foxglove"``: its episodes served live, as a run's are.

A policy being evaluated is watched the way ``robchair sim --live`` is watched: the environment's
runtime gets a :class:`robchair.observers.live.LiveObserver` with a
:class:`robchair.viz.foxglove_live.FoxgloveSink`, so the same topics, schemas and frame ids go out
over a Foxglove WebSocket on localhost (TF, the depth cloud, the laser scan, the sonar ranges and
cones, the episode's map as ``nav_msgs/OccupancyGrid``, its VHV boxes as markers, odometry, the safety
layer's decisions). Open ``ws://localhost:PORT`` in Foxglove or Lichtblick with
``assets/foxglove/robchair_layout.json``. Every ``step`` is one runtime cycle, so the view follows the
steps as they are taken; without a client nothing is built or serialised (the observer only asks the
server whether a channel has a subscriber).

Usage::

    env = gymnasium.make("RobChair/Navigation-v1", render_mode="foxglove", live_port=8765)
    # live_port 0: any free port; env.unwrapped.live.url says which

The server starts when the environment is built (a port in use raises there) and stops at ``close()``.
"""

from __future__ import annotations

from typing import Any

from sim.envs.errors import NavigationEnvError

RENDER_MODE = "foxglove"
#: the port of ``robchair sim --live`` (robchair.viz.foxglove_live.DEFAULT_PORT)
DEFAULT_PORT = 8765


class LiveView:
    """The environment's live server and the observer that feeds it.

    Args:
        port: TCP port on localhost (0: any free one; :attr:`url` names it).

    Raises:
        NavigationEnvError: the port is not a port, it is in use, or the Foxglove SDK is missing.
    """

    def __init__(self, port: int = DEFAULT_PORT) -> None:
        from robchair.platform.errors import ConfigError

        check_live(RENDER_MODE, port)
        from robchair.observers.live import LiveObserver

        try:
            from robchair.viz.foxglove_live import FoxgloveSink

            self.sink = FoxgloveSink(port)
        except ConfigError as exc:
            raise NavigationEnvError(f"render_mode={RENDER_MODE!r}: {exc}") from None
        self.url: str = self.sink.url
        self.observer = LiveObserver([self.sink])

    def attach(self, runtime: Any) -> None:
        """Observe ``runtime`` (before its ``start``); idempotent, and moves to a rebuilt runtime."""
        if self.observer not in runtime.observers:
            runtime.observers.append(self.observer)

    def stats(self) -> dict[str, Any]:
        """What was sent and dropped so far (:meth:`robchair.observers.live.LiveObserver.stats`)."""
        return self.observer.stats()

    def close(self) -> None:
        """Stop the server (after the runtime's last episode ended: its queue is drained then)."""
        self.observer.close()


def check_live(render_mode: str | None, port: int | None) -> None:
    """Refuse ``live_port`` (the environment's keyword) without ``render_mode="foxglove"``, and a value
    that is not a TCP port, before anything is built.

    Raises:
        NavigationEnvError: naming the value and what was expected.
    """
    if port is None:
        return
    if render_mode != RENDER_MODE:
        raise NavigationEnvError(f"live_port={port!r} needs render_mode={RENDER_MODE!r}")
    if not (isinstance(port, int) and not isinstance(port, bool) and 0 <= port < 65536):
        raise NavigationEnvError(f"live_port={port!r}: expected a TCP port 0-65535 (0: any free)")


def open_live(render_mode: str | None, port: int | None) -> LiveView | None:
    """The live view ``render_mode`` asks for (None for the other modes), on ``port`` (None:
    :data:`DEFAULT_PORT`).

    Raises:
        NavigationEnvError: as :func:`check_live`, or the port is in use.
    """
    check_live(render_mode, port)
    if render_mode != RENDER_MODE:
        return None
    return LiveView(DEFAULT_PORT if port is None else port)
