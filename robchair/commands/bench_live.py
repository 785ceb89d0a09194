"""`robchair bench sim --live`: what the live view (``robchair sim --live``) costs the loop.

Workload: the ``2 cores`` configuration of ``robchair bench sim`` (Kinect v2 at 30 Hz, six sonars at
20 Hz, the map on its own thread), run three ways in the same invocation, alternating so that all
three see the same machine load:

* ``off``: no live view (the baseline);
* ``no client``: the Foxglove server listening, nobody connected;
* ``client``: a client started by the bench (in a child process, as a viewer is), connected and
  subscribed to every channel before the loop starts, receiving everything (it does not decode).

Measured: the process's CPU time (``time.process_time``: the loop, the mapping and capture threads,
the publisher thread and the server's threads) from the episode's start to its end (after the live
queue has drained), per simulated second. Targets: at
most 5 % more than ``off`` with a client, and nothing (at most 1 %, the measurement's noise) without
one. Reported: medians of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from typing import Any

from robchair.loop_types import Observer

MODES = ("off", "no client", "client")
TARGETS = {"no client": 0.01, "client": 0.05}  # extra CPU time per simulated second, fraction of "off"
SUBSCRIBE_TIMEOUT_S = 30.0
#: subscribe once no channel was advertised for this long, s (as a viewer does; a subscription sent the
#: instant a channel is advertised can reach the server before it knows the channel, and is refused)
SUBSCRIBE_AFTER_S = 0.1


class BenchClient:
    """A Foxglove WebSocket client in a child process (:func:`client_main`): its CPU time, and that of
    the WebSocket library's reader thread, is not the live view's."""

    def __init__(self, port: int) -> None:
        self.port = int(port)
        self.frames = 0
        self.bytes = 0
        self.subscribed = threading.Event()
        self._proc: subprocess.Popen[str] | None = None
        self._reader = threading.Thread(target=self._read, name="bench-live-client-out", daemon=True)

    def start(self) -> None:
        code = "from robchair.commands.bench_live import client_main; client_main()"
        self._proc = subprocess.Popen([sys.executable, "-c", code, str(self.port)], stdout=subprocess.PIPE,
                                      text=True)  # fmt: skip
        self._reader.start()

    def stop(self) -> None:
        """Wait for the client to end (the server closes the connection at the end of the run)."""
        if self._proc is not None:
            try:
                self._proc.wait(30.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._reader.join(5.0)

    def _read(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        for line in self._proc.stdout:
            word, *rest = line.split()
            if word == "subscribed":
                self.subscribed.set()
            elif word == "received" and len(rest) == 2:
                self.frames, self.bytes = int(rest[0]), int(rest[1])


def client_main() -> None:
    """The bench client (``python -c ... PORT``): subscribes to every advertised channel, receives until
    the server closes, prints ``subscribed`` and at the end ``received FRAMES BYTES``."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    frames = nbytes = 0
    url = f"ws://127.0.0.1:{int(sys.argv[1])}"
    with connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:  # type: ignore[list-item]
        pending: list[dict[str, int]] = []
        last_advertise, next_id = 0.0, 1
        while True:
            if pending and time.monotonic() - last_advertise > SUBSCRIBE_AFTER_S:
                ws.send(json.dumps({"op": "subscribe", "subscriptions": pending}))
                pending = []
                print("subscribed", flush=True)
            try:
                raw = ws.recv(timeout=0.05)
            except TimeoutError:
                continue
            except ConnectionClosed:
                break
            if isinstance(raw, bytes):
                frames, nbytes = frames + 1, nbytes + len(raw)
                continue
            msg = json.loads(raw)
            if msg.get("op") == "advertise":
                last_advertise = time.monotonic()
                for ch in msg["channels"]:
                    pending.append({"id": next_id, "channelId": ch["id"]})
                    next_id += 1
    print("received", frames, nbytes, flush=True)


class CpuWindow(Observer):
    """CPU time of this process from the episode's start to its end (once the client subscribed)."""

    def __init__(self, client: BenchClient | None = None) -> None:
        self.client = client
        self.cpu_s = 0.0
        self._t0 = 0.0

    def episode_start(self, runtime: Any) -> None:
        if self.client is not None:  # the channels exist now: measure once the client subscribed
            if not self.client.subscribed.wait(SUBSCRIBE_TIMEOUT_S):
                raise RuntimeError(f"the bench client did not subscribe within {SUBSCRIBE_TIMEOUT_S:g} s")
            time.sleep(0.05)  # the subscription requests reach the server
        self._t0 = time.process_time()

    def episode_end(self, runtime: Any, result: Any) -> None:
        self.cpu_s = time.process_time() - self._t0


def measure(mode: str, scenario: str, duration: float, seed: int, map_kind: str) -> dict[str, Any]:
    """One run with the live view ``mode`` (one of :data:`MODES`); CPU s per simulated s and counts."""
    from robchair.observers.live import LiveObserver
    from robchair.scenario import run_scenario

    live, client = None, None
    if mode != "off":
        from robchair.viz.foxglove_live import FoxgloveSink

        sink = FoxgloveSink(port=0)
        live = LiveObserver([sink])
        if mode == "client":
            client = BenchClient(sink.port)
            client.start()
    window = CpuWindow(client)
    try:
        res = run_scenario(scenario, duration=duration, sensor="kinect2", seed=seed, progress=False,
                           write=False, mapping_thread=True, pipeline=True, sonar_hz=20.0, raycast_threads=1,
                           ground_truth_map=False, map_kind=map_kind,
                           observers=[live, window] if live is not None else [window])  # fmt: skip
    finally:
        if live is not None:
            live.close()
        if client is not None:
            client.stop()
    return {
        "cpu_s_per_sim_s": window.cpu_s / max(res.sim_time_s, 1e-9),
        "sim_time_s": res.sim_time_s,
        "cycles": res.cycles,
        "client_frames": client.frames if client is not None else None,
        "client_mb": client.bytes / 1e6 if client is not None else None,
        "live": res.extra.get("live"),
    }


def run_live_bench(args: argparse.Namespace) -> int:
    """``robchair bench sim --live`` (the options of ``robchair bench sim``: duration, repeats, scenario,
    map, out)."""
    from robchair.commands.bench_output import results_dir, write_results
    from robchair.commands.sim import retain_freed_memory
    from robchair.platform.errors import RobChairError

    if args.duration <= 0 or args.repeats < 1:
        raise RobChairError(f"--duration must be > 0 and --repeats >= 1, got {args.duration}, {args.repeats}")
    out = results_dir(args, "sim-live")  # refused before anything is measured
    retain_freed_memory()
    load0 = os.getloadavg()
    measure("off", args.scenario, 0.1, 0, args.map)  # warm-up (imports, kernels): not timed
    runs: dict[str, list[dict[str, Any]]] = {m: [] for m in MODES}
    for k in range(args.repeats):  # alternate the modes: the same machine load for all three
        for mode in MODES:
            runs[mode].append(measure(mode, args.scenario, args.duration, k, args.map))
    load1 = os.getloadavg()
    med = {m: statistics.median(r["cpu_s_per_sim_s"] for r in runs[m]) for m in MODES}
    print(f"robchair bench sim --live: {args.scenario}, {args.map} map, Kinect v2, {args.duration:g} sim s "
          f"per run, median of {args.repeats}")  # fmt: skip
    print(f"{'live view':12s} {'CPU s / sim s':>14s} {'extra':>8s} {'target':>8s}  verdict   client frames")
    verdicts = {}
    for mode in MODES:
        extra = med[mode] / med["off"] - 1.0
        target = TARGETS.get(mode)
        verdict = "-" if target is None else ("met" if extra <= target else "missed")
        verdicts[mode] = verdict
        frames = runs[mode][-1]["client_frames"]
        print(f"{mode:12s} {med[mode]:14.3f} {100 * extra:7.1f}% "
              f"{'' if target is None else f'{100 * target:.0f} %':>8s}  {verdict:8s}  "
              f"{'' if frames is None else frames}")  # fmt: skip
    result = {"scenario": args.scenario, "map_kind": args.map, "duration_s": args.duration,
              "repeats": args.repeats, "targets_extra_fraction": TARGETS, "median_cpu_s_per_sim_s": med,
              "verdicts": verdicts, "runs": runs}  # fmt: skip
    write_results(out, "sim_live", result, load0, load1)
    return 0
