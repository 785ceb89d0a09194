"""The PyBullet world: a headless (DIRECT) physics client at 240 Hz with a floor plane.

Each :class:`World` owns its own client id, so several worlds (tests, benchmarks) can live in one
process. Time is counted in integer physics steps and exposed as nanoseconds (``now_ns``) so simulated
time stamps are exact and reproducible.
"""

from __future__ import annotations

from typing import Any

from sim.errors import SimError

PHYSICS_HZ = 240
GRAVITY = 9.81


class World:
    """A PyBullet physics client with gravity and a floor plane at z = 0.

    Args:
        physics_hz: Physics rate; the time step is ``1 / physics_hz``.
        gui: Open PyBullet's GUI instead of the headless DIRECT client (needs a display).
    """

    def __init__(self, physics_hz: int = PHYSICS_HZ, gui: bool = False) -> None:
        import pybullet as p
        import pybullet_data

        if physics_hz <= 0:
            raise SimError(f"physics_hz must be positive, got {physics_hz}")
        self.physics_hz = int(physics_hz)
        self.dt = 1.0 / self.physics_hz
        self.client = p.connect(p.GUI if gui else p.DIRECT)
        if self.client < 0:
            raise SimError("could not start a PyBullet physics client")
        self.steps = 0
        self._pre_step: list[Any] = []
        p.resetSimulation(physicsClientId=self.client)
        p.setGravity(0, 0, -GRAVITY, physicsClientId=self.client)
        p.setTimeStep(self.dt, physicsClientId=self.client)
        # deterministic: the same inputs give the same contacts in the same order
        p.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=self.client)
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=self.client)
        self.plane = p.loadURDF("plane.urdf", physicsClientId=self.client)
        p.changeDynamics(
            self.plane,
            -1,
            lateralFriction=1.0,
            rollingFriction=0.0,
            spinningFriction=0.0,
            physicsClientId=self.client,
        )

    @property
    def time(self) -> float:
        """Simulated time, s."""
        return self.steps / self.physics_hz

    def now_ns(self) -> int:
        """Simulated time in integer nanoseconds (exact: steps * 1e9 / rate)."""
        return self.steps * 1_000_000_000 // self.physics_hz

    def add_pre_step(self, fn: Any) -> None:
        """Register ``fn()`` to run before every physics step (motor controllers, scripted people)."""
        self._pre_step.append(fn)

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps, running the pre-step callbacks before each."""
        import pybullet as p

        for _ in range(n):
            for fn in self._pre_step:
                fn()
            p.stepSimulation(physicsClientId=self.client)
            self.steps += 1

    def close(self) -> None:
        """Disconnect the client (idempotent)."""
        import pybullet as p

        if self.client >= 0:
            try:
                p.disconnect(physicsClientId=self.client)
            except p.error:  # already disconnected
                pass
            self.client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort when a caller forgets close()
        try:
            self.close()
        except Exception:
            pass
