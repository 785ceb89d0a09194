"""Async vector envs with spinning workers (robchair.envs.vector): Gymnasium's results, another wait."""

from __future__ import annotations

import multiprocessing as mp
import threading
import time
from typing import Any

import gymnasium
import numpy as np
import pytest

from robchair.envs.vector import SpinningPipe, make_spinning_async


def _roll(envs: gymnasium.vector.VectorEnv, steps: int) -> list[tuple[Any, ...]]:
    obs, _ = envs.reset(seed=7)
    out: list[tuple[Any, ...]] = [(obs,)]
    actions = np.random.default_rng(3).integers(0, 2, (steps, envs.num_envs))
    for a in actions:  # CartPole episodes end within these steps: autoreset runs in the workers too
        obs, rew, term, trunc, _ = envs.step(a)
        out.append((obs, rew, term, trunc))
    envs.close()
    return out


def test_spinning_workers_give_gymnasiums_async_results_bit_for_bit() -> None:
    plain = _roll(gymnasium.make_vec("CartPole-v1", num_envs=2, vectorization_mode="async"), 120)
    spun = _roll(make_spinning_async("CartPole-v1", 2, spin_s=1e-3), 120)
    assert any(bool(r[2].any()) for r in plain[1:]), "no episode ended: autoreset not exercised"
    for a, b in zip(plain, spun, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


def test_a_message_sent_within_the_spin_is_caught_spinning_and_a_late_one_after_blocking() -> None:
    a, b = mp.Pipe()
    pipe = SpinningPipe(b, spin_s=0.5)
    threading.Timer(0.01, a.send, args=("soon",)).start()
    assert pipe.recv() == "soon"
    assert (pipe.caught, pipe.blocked) == (1, 0)

    short = SpinningPipe(b, spin_s=0.0)
    threading.Timer(0.05, a.send, args=("late",)).start()
    t0 = time.perf_counter()
    assert short.recv() == "late"
    assert time.perf_counter() - t0 >= 0.04  # it waited for the message, blocking
    assert (short.caught, short.blocked) == (0, 1)
    a.close()
    b.close()


@pytest.mark.parametrize("spin", [-1e-3, float("nan"), float("inf")])
def test_a_bad_spin_is_refused_naming_it(spin: float) -> None:
    with pytest.raises(ValueError, match="spin_s="):
        make_spinning_async("CartPole-v1", 2, spin_s=spin)


def test_a_worker_of_ones_own_is_refused() -> None:
    with pytest.raises(ValueError, match="worker"):
        make_spinning_async("CartPole-v1", 2, vector_kwargs={"worker": print})
