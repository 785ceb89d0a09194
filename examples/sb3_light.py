"""Train a navigation policy on the light observation with Stable-Baselines3, then evaluate it.

Stable-Baselines3 is not a dependency of the project; install it yourself::

    pip install "stable-baselines3>=2.3"

Train (PPO on ``RobChair/Navigation-v1``, four worker processes, one million agent steps by default;
each worker draws a new chair every episode)::

    python examples/sb3_light.py --steps 1000000 --envs 4 --model out/sb3_light.zip

Evaluate with the project's evaluation command, beside the classical baseline and random actions,
on the same seeds (``MODULE:CALLABLE`` is imported from the current folder)::

    ROBCHAIR_SB3_MODEL=out/sb3_light.zip robchair nav-eval --env RobChair/Navigation-v1 \\
        --episodes 100 --policy examples.sb3_light:policy --policy baseline --policy random

The same works on random floors (``--env RobChair/NavigationRooms-v1``): training draws floors from
:data:`sim.rooms.TRAIN_SEEDS`, ``nav-eval`` from the disjoint :data:`sim.rooms.EVAL_SEEDS`.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

MODEL_ENV = "ROBCHAIR_SB3_MODEL"


INSTALL = "pip install 'stable-baselines3>=2.3'"


def _ppo() -> Any:
    """Stable-Baselines3's PPO, imported only when needed (``--help`` works without it).

    Raises:
        SystemExit: Stable-Baselines3 is not installed (one line naming the install command, exit 2).
    """
    try:
        from stable_baselines3 import PPO
    except ModuleNotFoundError:
        print(f"sb3_light: stable-baselines3 is not installed; {INSTALL}", file=sys.stderr)
        raise SystemExit(2) from None
    return PPO


def policy(env: Any) -> Any:
    """``nav-eval`` factory: the trained model (path in ``$ROBCHAIR_SB3_MODEL``) as ``policy(obs, info)``."""
    path = os.environ.get(MODEL_ENV, "out/sb3_light.zip")
    model = _ppo().load(path, device="cpu")

    def act(obs: Any, info: dict[str, Any]) -> Any:
        action, _ = model.predict(obs, deterministic=True)
        return action

    return act


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--env", default="RobChair/Navigation-v1")
    ap.add_argument("--steps", type=int, default=1_000_000, help="agent steps of training")
    ap.add_argument("--envs", type=int, default=4, help="worker processes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--model", default="out/sb3_light.zip")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    PPO = _ppo()
    import gymnasium
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    import sim.envs  # noqa: F401  (registers the ids)

    if args.env not in gymnasium.registry:
        raise SystemExit(f"sb3_light: --env {args.env!r}: not a registered id")
    venv = make_vec_env(args.env, n_envs=args.envs, seed=args.seed, vec_env_cls=SubprocVecEnv)
    model = PPO(
        "MultiInputPolicy",
        venv,
        n_steps=512,
        batch_size=256,
        gamma=0.99,
        learning_rate=3e-4,
        ent_coef=0.01,
        seed=args.seed,
        verbose=1,
        device="cpu",
    )
    model.learn(total_timesteps=args.steps)
    os.makedirs(os.path.dirname(args.model) or ".", exist_ok=True)
    model.save(args.model)
    venv.close()
    print(
        f"saved {args.model}; evaluate with: {MODEL_ENV}={args.model} robchair nav-eval "
        f"--env {args.env} --policy examples.sb3_light:policy --policy baseline"
    )


if __name__ == "__main__":
    main()
