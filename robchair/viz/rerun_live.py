"""Rerun while the run happens: the live view's messages (:mod:`robchair.observers.live`) logged to a
recording stream with the entity paths and timeline of ``recording.rrd``
(:class:`robchair.viz.rerun_recording.MessageLogger`).

The stream goes to a running viewer (``rerun``, then ``robchair sim --rerun``; gRPC, the SDK's default
address unless ``url`` is given), or is served for viewers to connect to (``serve=True``), or goes to
a stream the caller made (e.g. one with a memory sink).
"""

from __future__ import annotations

import logging
from typing import Any

from robchair.observers.live import LiveSink
from robchair.platform.frames import BASE_LINK, ODOM
from robchair.viz.rerun_recording import APPLICATION_ID, MessageLogger, import_rerun

log = logging.getLogger(__name__)


class RerunSink(LiveSink):
    """Logs every live message to a Rerun recording stream.

    Args:
        url: a viewer's gRPC address (default: the SDK's, ``rerun+http://127.0.0.1:9876/proxy``).
        serve: serve the stream (``rr.serve_grpc``; its address is :attr:`url`) instead of connecting.
        recording: log to this stream instead (no connection is made).
        recording_id: the recording's id in the viewer.

    Raises:
        RunFolderError: the Rerun SDK is not installed.
    """

    def __init__(self, url: str | None = None, serve: bool = False, recording: Any = None,
                 recording_id: str | None = None) -> None:  # fmt: skip
        rr = import_rerun()
        self._rr = rr
        self.url = url
        if recording is not None:
            self.rec = recording
        else:
            self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
            if serve:
                self.url = rr.serve_grpc(recording=self.rec)
            elif url:
                self.rec.connect_grpc(url)
            else:
                self.rec.connect_grpc()
        self._logger: MessageLogger | None = None
        self._t0_ns = 0

    def open(self, topics: dict[str, str], parents: dict[str, str], t0_ns: int, store: Any) -> None:
        rr = self._rr
        self._t0_ns = int(t0_ns)
        self._logger = MessageLogger(rr, self.rec, parents, {ODOM, BASE_LINK})  # /tf moves them
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def send(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        assert self._logger is not None
        self._logger.log(topic, msgtype, (int(stamp_ns) - self._t0_ns) / 1e9, msg)

    def close(self) -> None:
        if self._logger is not None:
            self._logger.flush()
        try:
            self.rec.flush()
        except RuntimeError as exc:  # no viewer came: the run itself is done and written
            log.warning("rerun: the stream could not be delivered (%s); start `rerun` before the run", exc)
