"""Gymnasium Async vector envs whose workers spin briefly on their pipe before they block.

Gymnasium's :class:`gymnasium.vector.AsyncVectorEnv` runs each env in a worker process that blocks in
``pipe.recv()`` between steps. On a virtual machine a blocked worker's vCPU goes idle; waking it costs
latency, and the env step that follows runs on caches the host has meanwhile given to others (``robchair
bench env``'s "1 ms idle per step" row measures that step against one back to back). A worker made by
:func:`spinning_worker` polls its pipe for up to ``spin_s`` seconds first and blocks only after that, so
in a training loop that steps every few milliseconds the vCPU never idles between steps. The cost is
CPU: a worker burns up to ``spin_s`` per step while it waits (for the other workers or for the policy in
the parent), so keep ``spin_s`` below the env's step time and do not give more workers than cores.

Everything else is Gymnasium's own worker (commands, autoreset, shared memory, errors): the wrapper only
changes how the worker waits for the next command, so results are those of the plain Async vector env,
bit for bit (``tests/robchair/test_env_vector.py``).

Example::

    from robchair.envs.vector import make_spinning_async
    envs = make_spinning_async("RobChair/Navigation-v1", num_envs=2)
"""

from __future__ import annotations

import functools
import time
from typing import Any

#: Default longest spin per wait, s (about half the light env's step on one core).
SPIN_S = 2e-3


class SpinningPipe:
    """A :class:`multiprocessing.connection.Connection` whose :meth:`recv` polls for up to ``spin_s`` s
    (non-blocking ``poll(0)`` in a loop) before it blocks; every other method is the connection's."""

    def __init__(self, pipe: Any, spin_s: float) -> None:
        self._pipe = pipe
        self.spin_s = float(spin_s)
        #: waits that found their message while spinning / that blocked after the spin (diagnostics)
        self.caught = 0
        self.blocked = 0

    def recv(self) -> Any:
        end = time.perf_counter() + self.spin_s
        while True:
            if self._pipe.poll(0):
                self.caught += 1
                break
            if time.perf_counter() >= end:
                self.blocked += 1
                break
        return self._pipe.recv()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._pipe, name)


def spinning_worker(index: int, env_fn: Any, pipe: Any, parent_pipe: Any, *rest: Any, spin_s: float) -> None:
    """Gymnasium's Async worker (``gymnasium.vector.async_vector_env._async_worker``, same arguments)
    waiting on a :class:`SpinningPipe`. Bind ``spin_s`` (``functools.partial``) and give it as
    ``AsyncVectorEnv(..., worker=...)``.

    Raises:
        ValueError: ``spin_s`` is negative or not finite.
        ImportError: the installed Gymnasium has no ``_async_worker`` to wrap (tested with 1.x).
    """
    from gymnasium.vector.async_vector_env import _async_worker

    spinning: Any = SpinningPipe(pipe, _checked(spin_s))  # a Connection in all but its recv
    _async_worker(index, env_fn, spinning, parent_pipe, *rest)


def _checked(spin_s: float) -> float:
    s = float(spin_s)
    if not (s >= 0.0 and s < float("inf")):
        raise ValueError(f"spin_s={spin_s!r}: expected a finite number of seconds >= 0")
    return s


def make_spinning_async(env_id: str, num_envs: int, *, spin_s: float = SPIN_S, **kwargs: Any) -> Any:
    """``gymnasium.make_vec(env_id, num_envs, vectorization_mode="async", ...)`` with
    :func:`spinning_worker` workers spinning up to ``spin_s`` s; ``kwargs``: ``vector_kwargs`` (merged,
    ``worker`` excluded) and the env's keyword arguments, as ``make_vec`` takes them.

    Raises:
        ValueError: ``spin_s`` is negative or not finite, or ``vector_kwargs`` names a ``worker``.
    """
    import gymnasium

    spin = _checked(spin_s)
    vector_kwargs = dict(kwargs.pop("vector_kwargs", None) or {})
    if "worker" in vector_kwargs:
        raise ValueError("vector_kwargs['worker']: make_spinning_async sets the worker itself")
    vector_kwargs["worker"] = functools.partial(spinning_worker, spin_s=spin)
    return gymnasium.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="async", vector_kwargs=vector_kwargs, **kwargs
    )
