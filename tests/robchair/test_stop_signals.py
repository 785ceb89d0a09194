"""SIGINT, SIGTERM and SIGHUP on a driving `robchair run` / `robchair sim` stop the chair first.

The requirement (issue "a chair that stops on every exit"): `kill`, `timeout`, `systemctl stop`,
`docker stop` and a closed terminal send SIGTERM or SIGHUP; each must command zero speeds and the
Roboteq's emergency stop (``!EX``, Roboteq user manual, "Emergency stop") within 50 ms, print one line
on stderr, leave no staging folder, and exit with the shell's convention 128 + signal number
(POSIX: SIGHUP 1, SIGINT 2, SIGTERM 15 -> 129, 130, 143).

The controller is an emulator in this process on a pty, on the machine's monotonic clock, so what
arrived, and when, is read on the controller's side of the serial line, not from the driver.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hw.clock import MonotonicClock
from hw.roboteq.emulator import RoboteqEmulator

ROOT = Path(__file__).resolve().parents[2]
STOP_WITHIN_NS = 50_000_000  # the requirement: zero speeds and !EX within 50 ms of the signal


def _env() -> dict[str, str]:
    return {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}


def _default_stop_signals() -> None:
    """In the child before exec: SIGINT, SIGTERM and SIGHUP at their default dispositions.

    A test run under ``nohup`` (SIGHUP ignored) or as a background job of a non-interactive shell
    (SIGINT ignored) passes those dispositions on, and the command rightly keeps a stop signal its
    parent ignored (POSIX ``exec``: ignored signals stay ignored). The command must meet the signal
    as it would from a terminal, ``kill`` or ``systemctl``.
    """
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)


def _spawn(args: list[str], cwd: Path) -> subprocess.Popen:  # type: ignore[type-arg]
    """``robchair ARGS`` in a child process with pipes, the test's environment and default signals."""
    return subprocess.Popen(
        [sys.executable, "-m", "robchair.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, env=_env(), cwd=cwd, preexec_fn=_default_stop_signals,
    )  # fmt: skip


def _wait_for(condition, bound_s: float, proc: subprocess.Popen) -> None:  # type: ignore[type-arg]
    """Poll ``condition`` every 10 ms for at most ``bound_s`` (fail early if the process ended)."""
    deadline = time.monotonic() + bound_s
    while not condition():
        if proc.poll() is not None:
            _, err = proc.communicate()
            pytest.fail(f"the command ended (rc {proc.returncode}) before the condition: {err[-2000:]}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"condition not met within {bound_s} s")
        time.sleep(0.01)


def _speeds(emu: RoboteqEmulator) -> list[tuple[int, int, int]]:
    """(monotonic ns, channel, RPM) of every ``!S`` the controller received."""
    out = []
    for t, line in list(emu.received):
        m = re.fullmatch(r"!S (\d) (-?\d+)", line)
        if m:
            out.append((t, int(m.group(1)), int(m.group(2))))
    return out


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_on_run_real_zeroes_the_motors_and_latches_the_stop_within_50_ms(
    tmp_path: Path, sig: signal.Signals
) -> None:
    with RoboteqEmulator(clock=MonotonicClock()) as emu:
        cfg = tmp_path / "real.toml"
        cfg.write_text(f'[real]\nport = "{emu.device_path}"\n', encoding="utf-8")
        out = tmp_path / "R"
        proc = _spawn(
            ["run", "--backend", "real", "--config", str(cfg), "--route",
             str(ROOT / "examples/routes/short_turn.toml"), "--duration", "30", "--out", str(out)],
            tmp_path,
        )  # fmt: skip
        _wait_for(lambda: any(rpm != 0 for _, _, rpm in _speeds(emu)), 120.0, proc)
        t_sig = time.monotonic_ns()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        # the emulator's reader thread may not have read the last bytes the process wrote before it
        # ended: wait (bounded) until it has, so a lagging reader is not taken for a missing stop
        end = time.monotonic() + 2.0
        while not any(line == "!EX" for _, line in list(emu.received)) and time.monotonic() < end:
            time.sleep(0.01)
        received = [(t, line) for t, line in list(emu.received) if t >= t_sig]
        estopped = emu.estop
    after = [(t, ch, rpm) for t, ch, rpm in _speeds(emu) if t >= t_sig]
    zero = {ch: t for t, ch, rpm in reversed(after) if rpm == 0}
    ex = [t for t, line in received if line == "!EX"]
    assert set(zero) == {1, 2}, received
    assert max(zero.values()) - t_sig <= STOP_WITHIN_NS, (zero, t_sig)
    assert ex and ex[0] - t_sig <= STOP_WITHIN_NS, (ex, t_sig)
    assert all(rpm == 0 for t, _, rpm in after if t > ex[0])  # nothing moved it again
    assert estopped
    assert proc.returncode == 128 + sig
    assert _ours(err) == [f"robchair run: stopped by {sig.name}; motors stopped"], err
    assert not out.exists()
    assert not [p.name for p in tmp_path.iterdir() if ".partial-" in p.name]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_on_sim_prints_one_line_and_leaves_no_staging_folder(
    tmp_path: Path, sig: signal.Signals
) -> None:
    out = tmp_path / "Z"
    proc = _spawn(["sim", "--out", str(out), "--no-progress", "--no-pictures", "--duration", "30"], tmp_path)

    def driving() -> bool:  # the loop runs once the time series has rows below its header
        return any(len(p.read_bytes().splitlines()) > 2 for p in tmp_path.glob(".Z.partial-*/timeseries.csv"))

    _wait_for(driving, 240.0, proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig
    assert _ours(err) == [f"robchair sim: stopped by {sig.name}; motors stopped"], err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def _ours(err: str) -> list[str]:
    """stderr without pybullet's import banner and the one-time note while numba compiles the kernels
    (printed before the loop starts, only when the kernel cache is cold)."""
    return [
        line
        for line in err.splitlines()
        if not line.startswith("pybullet build time:")
        and not (line.startswith("compiling ") and "(first run only" in line)
    ]


def _command(name: str, inputs: Path, out: Path) -> list[str]:
    """A run of ``name`` long enough to be stopped while it drives, writing into ``out``."""
    if name == "sim":
        return ["sim", "--out", str(out), "--no-progress", "--no-pictures", "--duration", "30"]
    cfg = inputs / "cfg.toml"
    cfg.write_text("[emulated]\nsonars = false\n[runtime]\nrate_hz = 10.0\n", encoding="utf-8")
    return ["run", "--backend", "emulated", "--config", str(cfg), "--duration", "60", "--out", str(out),
            "--route", str(ROOT / "examples/routes/short_turn.toml")]  # fmt: skip


@pytest.mark.parametrize("command", ["sim", "run"])
def test_a_command_stopped_by_sigterm_removes_the_parent_folders_it_created(
    tmp_path: Path, command: str
) -> None:
    """``--out new/a/b/out`` where only the working folder existed: the command creates ``new/a/b`` for
    its staging folder; stopped while it drives, it leaves the working folder as it found it (the rule
    of :mod:`robchair.outdir`: a command that does not finish leaves no new folder behind, neither the
    staging folder nor a parent created for it)."""
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    work = tmp_path / "work"
    work.mkdir()
    parent = work / "new" / "a" / "b"
    proc = _spawn(_command(command, inputs, parent / "out"), work)

    def driving() -> bool:  # the loop runs once the time series has rows below its header
        return any(len(p.read_bytes().splitlines()) > 2 for p in parent.glob(".out.partial-*/timeseries.csv"))

    _wait_for(driving, 240.0, proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert list(work.iterdir()) == [], sorted(str(p.relative_to(work)) for p in work.rglob("*"))


def test_a_stop_signal_while_the_parents_of_out_are_created_leaves_none_of_them(tmp_path) -> None:
    """SIGTERM arrives (sent by the process to itself) just after the second missing parent of
    ``new/a/out`` is made: the command ends by the signal, and neither ``new`` nor ``new/a`` is left (the
    rule of :mod:`robchair.outdir`: a command stopped by a signal leaves no new folder behind). It runs in
    a child process, so a signal that escapes the handler ends the child, not the test session."""
    script = textwrap.dedent(
        """
        import os, signal, sys
        from pathlib import Path
        from robchair.cli import stop_signals_raise
        from robchair.outdir import staged_output_dir
        from robchair.platform.errors import StopSignal

        root = Path(sys.argv[1])
        mkdir = Path.mkdir

        def mkdir_then_signal(self, *args, **kwargs):
            mkdir(self, *args, **kwargs)
            if self == root / "new" / "a":
                os.kill(os.getpid(), signal.SIGTERM)

        Path.mkdir = mkdir_then_signal
        try:
            with stop_signals_raise():
                with staged_output_dir(root / "new" / "a" / "out"):
                    sys.exit("the signal came before the output was staged")
        except StopSignal:
            sys.exit(7)
        sys.exit("no StopSignal")
        """
    )
    work = tmp_path / "w"
    work.mkdir()
    proc = subprocess.run([sys.executable, "-c", script, str(work)], capture_output=True, text=True,
                          env=_env(), timeout=120)  # fmt: skip
    assert proc.returncode == 7, (proc.returncode, proc.stderr[-2000:])
    assert list(work.iterdir()) == [], sorted(str(p.relative_to(work)) for p in work.rglob("*"))


def test_a_stop_signal_the_parent_ignores_stays_ignored_and_the_others_raise() -> None:
    """Under ``nohup`` (SIGHUP ignored) a closed terminal must not stop the command: POSIX keeps an
    ignored signal ignored across ``exec``, and ``nohup`` exists for that. SIGTERM, left at its default,
    still stops it; after the block every disposition is what it was."""
    from robchair.cli import stop_signals_raise
    from robchair.platform.errors import StopSignal

    before = {s: signal.getsignal(s) for s in (signal.SIGHUP, signal.SIGTERM)}
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with pytest.raises(StopSignal) as stopped, stop_signals_raise():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGHUP)  # ignored: nothing happens
            assert callable(signal.getsignal(signal.SIGTERM))
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)  # the handler runs at the next bytecode; never reached past it
        assert stopped.value.signo == signal.SIGTERM
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    finally:
        for s, h in before.items():
            signal.signal(s, h)


def test_a_stop_signal_while_numba_compiles_stops_the_motors_at_once_and_raises_after_the_compile() -> None:
    """SIGTERM arrives while the drive loop's thread compiles a kernel (a cold cache after an install).

    numba's compiler is Python driving LLVM: raised in the middle of it, the stop once came out as a
    lost signal (swallowed in an LLVM callback: the run drove on and exited 0), a "no compiled object
    yet" error, or a double free at exit. Here the handler stops the motors at once (zero speeds and
    ``!EX`` on the controller before the compile ends), and the StopSignal comes once it has ended, with
    the kernel compiled, and says the motors were stopped.
    """
    import numba
    from numba.core import event

    from robchair.cli import stop_signals_raise
    from robchair.platform.errors import StopSignal

    @numba.njit(cache=False)
    def kernel(x):  # a kernel no run has compiled: its first call compiles it in the loop
        return x + 1.0

    from robchair.backends import get_backend
    from robchair.platform.spec import load_spec
    from robchair.run_output import run_to_dir
    from robchair.sources import PolicySource

    backend = get_backend("emulated", {"timeout_s": 0.1, "sonars": False})
    emu = backend.extras["roboteq_emulator"]
    seen: dict[str, object] = {}

    class SignalAtCompileStart(event.Listener):  # type: ignore[misc]
        def on_start(self, _event: object) -> None:
            os.kill(os.getpid(), signal.SIGTERM)  # delivered now, inside the compile

        def on_end(self, _event: object) -> None:  # the compile is over: were the motors stopped?
            seen["estop_before_compile_ended"] = emu.estop
            seen["setpoints_before_compile_ended"] = emu.setpoints_rpm

    def policy(obs) -> tuple[float, float]:
        if obs.pose.x > 0.2:
            kernel(obs.pose.x)
            seen["policy_went_on"] = True
        return 0.6, 0.0

    listener = SignalAtCompileStart()
    event.register("numba:compile", listener)
    # SIGTERM at its default, as in a fresh command (a library this test process loaded earlier, e.g.
    # Ray, may have installed its own handler, which the command rightly leaves alone)
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with pytest.raises(StopSignal) as stopped, stop_signals_raise():
            run_to_dir(backend, PolicySource(policy), 6.0, None, spec=load_spec(), observers=[])
    finally:
        event.unregister("numba:compile", listener)
        signal.signal(signal.SIGTERM, previous)
    assert stopped.value.signo == signal.SIGTERM
    assert seen["estop_before_compile_ended"] is True
    assert seen["setpoints_before_compile_ended"] == (0.0, 0.0)
    assert "policy_went_on" not in seen  # raised where the kernel was called, once it was compiled
    assert len(kernel.overloads) == 1
    assert stopped.value.motors_stopped
    assert emu.estop and emu.setpoints_rpm == (0.0, 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.5, 1.5, 3.0, 5.0])
def test_sigterm_while_a_cold_cache_compiles_the_kernels_stops_run_with_143(tmp_path: Path, delay_s) -> None:
    """The first run after an install compiles its kernels with the motors enabled: a SIGTERM sent
    ``delay_s`` after it says so on stderr (while it compiles) ends it by the signal (exit 143,
    "motors stopped"), not with a lost signal, an error from a half-built kernel, or a crash at exit."""
    import threading

    cfg = tmp_path / "cfg.toml"
    cfg.write_text("[emulated]\nsonars = false\n[runtime]\nrate_hz = 10.0\n", encoding="utf-8")
    work = tmp_path / "w"
    work.mkdir()
    args = [sys.executable, "-m", "robchair.cli", "run", "--backend", "emulated", "--config", str(cfg),
            "--duration", "60", "--out", str(work / "out"), "--route",
            str(ROOT / "examples/routes/short_turn.toml")]  # fmt: skip
    env = {**_env(), "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}  # a cold cache
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env,
                            cwd=work, preexec_fn=_default_stop_signals)  # fmt: skip
    assert proc.stderr is not None
    lines: list[str] = []
    compiling = threading.Event()

    def read() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line.rstrip("\n"))
            if "compiling mapping kernels" in line:
                compiling.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    assert compiling.wait(240.0), lines
    time.sleep(delay_s)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=240)
    reader.join(timeout=10)
    assert proc.returncode == 128 + signal.SIGTERM, lines
    assert _ours("\n".join(lines)) == ["robchair run: stopped by SIGTERM; motors stopped"], lines
    assert list(work.iterdir()) == []
