"""Error root of the robchair package."""


class RobChairError(Exception):
    """Root of every error the robchair package raises on purpose."""


class ConfigError(RobChairError, ValueError):
    """A configuration file or value is invalid (the message names the field, value and expectation)."""


class StopSignal(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP asked the process to stop (raised by the CLI's signal handler).

    A KeyboardInterrupt, so it unwinds the way Ctrl-C always has: the drive loop commands zero speeds
    and the emergency stop before it propagates, and staging folders are removed on the way out.

    Attributes:
        signo: the signal's number (exit code ``128 + signo``).
        motors_stopped: set by the drive loop once zero speeds and the emergency stop were sent.
    """

    def __init__(self, signo: int) -> None:
        import signal

        super().__init__(signal.Signals(signo).name)
        self.signo = int(signo)
        self.motors_stopped = False
