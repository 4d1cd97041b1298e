"""Train a stable-baselines3 PPO exploration policy on the SLAM-wrapped environment.

The policy sees only the belief (``SlamWrapper`` observations: normalised scan, pose
uncertainty, egocentric belief raster, SLAM status) and is rewarded by it. Several
environments run in subprocesses; ``Monitor`` records the belief reward per episode.

Training worlds: ``VSlam/Explore-v0`` draws a new random world at every reset from the
environment's generator, seeded by ``--seed`` (environment ``i`` gets ``seed + i``);
evaluate on held-out worlds with ``agents/evaluate_agents.py --seed 1000`` or another
range nobody trained on.

Writes into ``--out``: ``final_model.zip`` (``PPO.load`` reads it), checkpoints
``checkpoints/ppo_<steps>_steps.zip``, ``monitor/`` CSVs (episode return and length per
environment), ``train_config.json``, ``logs/progress.csv`` (PPO's statistics per rollout:
losses, entropy, explained variance, fps); TensorBoard logs instead of ``logs/`` with
``--tensorboard DIR`` (needs ``pip install "vslam-gym[tensorboard]"``).

With ``--imitate AGENT`` the policy is first fitted to ``--imitation-steps`` steps of a
scripted agent (behaviour cloning, ``agents/imitation.py``; with ``--imitation-rounds``
> 1 followed by DAgger rounds; saved as ``bc_model.zip``), then trained by PPO; the
wall-time limit covers both.

    python agents/train_ppo.py --env VSlam/Explore-v0 --timesteps 50000 --out runs/ppo
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.append(str(Path(__file__).resolve().parent.parent))

import gymnasium as gym  # noqa: E402

import vslam_gym  # noqa: E402
from vslam_gym.evaluation import json_object, name_or_mapping  # noqa: E402


@dataclass(frozen=True)
class PpoSettings:
    """PPO hyper-parameters (stable-baselines3 names) used by :func:`train`.

    Attributes:
        n_steps: steps per environment per rollout.
        batch_size: minibatch size.
        n_epochs: optimisation epochs per rollout.
        learning_rate: Adam step size.
        gamma: discount factor per step (0.1 s).
        gae_lambda: GAE parameter.
        ent_coef: entropy bonus.
        clip_range: PPO clipping.
        net_arch: hidden layer sizes of the policy and value heads.
        cnn_output_dim: features of the belief-raster CNN (NatureCNN).
    """

    n_steps: int = 256
    batch_size: int = 64
    n_epochs: int = 5
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    ent_coef: float = 0.01
    clip_range: float = 0.2
    net_arch: tuple[int, ...] = (64, 64)
    cnn_output_dim: int = 128


def wrapper_kwargs(
    reward: str | Mapping[str, float] | None,
    slam_preset: str | None,
    frontier_cue: int = 0,
    shield: bool = False,
) -> dict[str, Any]:
    """``SlamWrapper`` arguments replacing the registration's: those given (not None).

    ``reward``: a reward preset name; ``slam_preset``: a ``SlamConfig`` preset name;
    ``frontier_cue``: > 0 adds the ``frontier`` observation of that many unknown lines
    (``BeliefObservationConfig.frontier_count``); ``shield``: the speed shield with its
    defaults (:class:`vslam_gym.shield.SpeedShield`).
    """
    given = {"reward": reward, "slam_config": slam_preset}
    kwargs = {k: v for k, v in given.items() if v is not None}
    if frontier_cue > 0:
        kwargs["observation"] = {"frontier_count": int(frontier_cue)}
    if shield:
        kwargs["shield"] = True
    return kwargs


def make_env_fn(
    env_id: str,
    seed: int,
    reward: str | Mapping[str, float] | None,
    slam_preset: str | None = None,
    frontier_cue: int = 0,
    shield: bool = False,
) -> Any:
    """A picklable constructor of one training environment (for ``make_vec_env``).

    ``reward``, ``slam_preset`` (a ``SlamConfig`` preset name), ``frontier_cue`` and
    ``shield`` replace the registration's wrapper arguments when given
    (:func:`wrapper_kwargs`).
    """
    kwargs = wrapper_kwargs(reward, slam_preset, frontier_cue, shield)
    spec = vslam_gym.explore_spec(env_id, **kwargs)

    def make() -> gym.Env:
        return gym.make(spec)

    return make


def train(
    env_id: str,
    timesteps: int,
    out: Path,
    n_envs: int = 2,
    seed: int = 0,
    reward: str | Mapping[str, float] | None = None,
    settings: PpoSettings | None = None,
    checkpoint_every: int = 10_000,
    tensorboard: str | None = None,
    progress_bar: bool = True,
    subprocesses: bool = True,
    max_minutes: float | None = None,
    slam_preset: str | None = None,
    imitate: str | None = None,
    imitation_steps: int = 12_000,
    imitation_epochs: int = 10,
    imitation_rounds: int = 1,
    frontier_cue: int = 0,
    shield: bool = False,
    imitate_config: dict[str, Any] | None = None,
) -> Path:
    """Train PPO and save ``out/final_model.zip``; returns its path.

    Args:
        env_id: a registered exploration id (``VSlam/Explore-v0`` or a shipped world's).
        timesteps: total environment steps over all environments.
        out: output directory (created).
        n_envs: parallel environments.
        seed: seed of PPO and of the environments (environment ``i``: ``seed + i``).
        reward: a reward preset name (``default``, ``d_opt``, ``coverage``) or a mapping
            of ``BeliefRewardConfig`` weights (e.g. ``{"collision": 10}``); None keeps
            the registration's.
        settings: PPO hyper-parameters.
        checkpoint_every: save a checkpoint every this many total steps (0: never).
        tensorboard: TensorBoard log directory, or None.
        progress_bar: show stable-baselines3's progress bar.
        subprocesses: run the environments in subprocesses (else in this process).
        max_minutes: stop training after this wall time [min] (the model trained so
            far is saved; ``train_config.json`` has ``trained_timesteps``).
        slam_preset: the wrapper's SLAM preset (``SlamConfig.preset``), e.g. ``"fast"``
            for about three times the throughput; None: the registration's
            (``"default"``).
        imitate: a scripted agent name: fit the policy to its demonstrations
            (:mod:`agents.imitation`) before PPO; ``out/bc_model.zip`` keeps the cloned
            policy. None: PPO from scratch.
        imitation_steps: demonstration steps per round (over ``n_envs`` worker
            processes).
        imitation_epochs: behaviour-cloning passes over the demonstrations per round.
        imitation_rounds: 1: behaviour cloning; more: DAgger rounds after it, the clone
            driving and the agent labelling (:func:`agents.imitation.clone_agent`).
        frontier_cue: > 0: the policy also observes that many nearest unknown lines of
            the map (the wrapper's ``frontier`` key); 0: the registration's observation.
        shield: train (and collect demonstrations) under the wrapper's speed shield
            (:class:`vslam_gym.shield.SpeedShield`); evaluate with ``--shield`` too.
        imitate_config: settings of the imitated scripted agent
            (:func:`agents.scripted.make_agent`), e.g. ``{"reach_distance": 0.5}``.
    """
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if tensorboard is not None and importlib.util.find_spec("tensorboard") is None:
        raise SystemExit('--tensorboard needs TensorBoard: pip install "vslam-gym[tensorboard]"')
    settings = settings or PpoSettings()
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    if imitate is not None:
        from agents.scripted import SCRIPTED_AGENTS, make_agent

        if imitate not in SCRIPTED_AGENTS:
            raise ValueError(f"--imitate must be one of {sorted(SCRIPTED_AGENTS)}, got {imitate!r}")
        make_agent(imitate, seed, imitate_config)  # bad settings fail before any work
    elif imitate_config:
        raise ValueError("imitate_config needs an agent to imitate (--imitate)")
    vec_env = make_vec_env(
        make_env_fn(env_id, seed, reward, slam_preset, frontier_cue, shield),
        n_envs=n_envs,
        seed=seed,
        monitor_dir=str(out / "monitor"),
        vec_env_cls=SubprocVecEnv if subprocesses and n_envs > 1 else DummyVecEnv,
    )
    policy_kwargs = {
        "net_arch": list(settings.net_arch),
        "features_extractor_kwargs": {"cnn_output_dim": settings.cnn_output_dim},
    }
    model = PPO(
        "MultiInputPolicy",
        vec_env,
        n_steps=settings.n_steps,
        batch_size=settings.batch_size,
        n_epochs=settings.n_epochs,
        learning_rate=settings.learning_rate,
        gamma=settings.gamma,
        gae_lambda=settings.gae_lambda,
        ent_coef=settings.ent_coef,
        clip_range=settings.clip_range,
        policy_kwargs=policy_kwargs,
        tensorboard_log=tensorboard,
        seed=seed,
        device="cpu",
        verbose=0,
    )
    if tensorboard is None:
        # PPO's training statistics per rollout into the run's own folder (SB3 would
        # otherwise make an empty folder in the system's temporary directory per run).
        from stable_baselines3.common.logger import configure

        model.set_logger(configure(str(out / "logs"), ["csv"]))

    class WallClockLimit(BaseCallback):
        """Stops training at a wall-clock deadline."""

        def __init__(self, seconds: float) -> None:
            super().__init__()
            self.deadline = time.perf_counter() + seconds

        def _on_step(self) -> bool:
            return time.perf_counter() < self.deadline

    config: dict[str, Any] = {}
    if imitate is not None:
        from agents.imitation import clone_agent

        config["imitation"] = clone_agent(
            model,
            env_id,
            imitate,
            imitation_steps,
            rounds=imitation_rounds,
            epochs=imitation_epochs,
            workers=n_envs if subprocesses else 1,
            wrapper_kwargs=wrapper_kwargs(reward, slam_preset, frontier_cue, shield),
            gamma=settings.gamma,
            work_dir=out,
            seed=seed,
            agent_config=imitate_config,
        )
        model.save(out / "bc_model.zip")
        if progress_bar:
            print(f"behaviour cloning of {imitate} done: {out / 'bc_model.zip'}; PPO follows")
    callbacks: list[BaseCallback] = []
    if max_minutes is not None:
        callbacks.append(WallClockLimit(max_minutes * 60.0 - (time.perf_counter() - start)))
    if checkpoint_every > 0:
        callbacks.append(
            CheckpointCallback(
                save_freq=max(1, checkpoint_every // n_envs),
                save_path=str(out / "checkpoints"),
                name_prefix="ppo",
            )
        )
    config = {
        **config,
        "env_id": env_id,
        "timesteps": timesteps,
        "n_envs": n_envs,
        "seed": seed,
        "reward": reward,
        "slam_preset": slam_preset,
        "frontier_cue": frontier_cue,
        "shield": shield,
        "settings": asdict(settings),
        "vslam_gym": vslam_gym.__version__,
    }
    learn_start = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=callbacks, progress_bar=progress_bar)
    config["wall_s"] = time.perf_counter() - start  # imitation included
    config["trained_timesteps"] = int(model.num_timesteps)
    config["steps_per_s"] = model.num_timesteps / (time.perf_counter() - learn_start)
    path = out / "final_model.zip"
    model.save(path)
    (out / "train_config.json").write_text(json.dumps(config, indent=2))
    vec_env.close()
    model.logger.close()  # its progress.csv (or TensorBoard files)
    return path


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default=vslam_gym.EXPLORE_ID, help="exploration env id")
    parser.add_argument("--timesteps", type=int, default=50_000, help="total env steps")
    parser.add_argument("--n-envs", type=int, default=2, help="parallel environments")
    parser.add_argument("--seed", type=int, default=0, help="PPO and environment seed")
    parser.add_argument(
        "--reward",
        default=None,
        type=name_or_mapping,
        help="reward preset (default|d_opt|coverage) or JSON weights, e.g. '{\"collision\": 10}'",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--checkpoint-every", type=int, default=10_000, help="steps, 0: never")
    parser.add_argument("--tensorboard", default=None, help="TensorBoard log directory")
    parser.add_argument("--n-steps", type=int, default=PpoSettings.n_steps)
    parser.add_argument("--batch-size", type=int, default=PpoSettings.batch_size)
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--max-minutes", type=float, default=None, help="wall-time limit")
    parser.add_argument(
        "--slam-preset",
        default=None,
        choices=("default", "thesis", "fast"),
        help="SLAM preset of the wrapper (default: the registration's, 'default')",
    )
    parser.add_argument(
        "--imitate",
        default=None,
        help="scripted agent to clone before PPO (e.g. frontier; default: none)",
    )
    parser.add_argument("--imitation-steps", type=int, default=12_000, help="steps per round")
    parser.add_argument("--imitation-epochs", type=int, default=10, help="epochs per round")
    parser.add_argument(
        "--imitation-rounds", type=int, default=1, help="1: cloning; more: DAgger rounds"
    )
    parser.add_argument(
        "--imitate-config",
        default=None,
        type=lambda text: json_object(text, "--imitate-config"),
        help="settings of the --imitate agent as JSON, as evaluate_agents.py --agent-config",
    )
    parser.add_argument(
        "--frontier-cue",
        type=int,
        default=0,
        help="observe this many nearest unknown lines of the map (default 0: off)",
    )
    parser.add_argument(
        "--shield",
        action="store_true",
        help="cap forward speed by the scan's free corridor (vslam_gym.shield)",
    )
    args = parser.parse_args(argv)
    reward = args.reward
    settings = PpoSettings(n_steps=args.n_steps, batch_size=args.batch_size)
    try:
        path = train(
            args.env,
            args.timesteps,
            args.out,
            n_envs=args.n_envs,
            seed=args.seed,
            reward=reward,
            settings=settings,
            checkpoint_every=args.checkpoint_every,
            tensorboard=args.tensorboard,
            progress_bar=not args.no_progress,
            max_minutes=args.max_minutes,
            slam_preset=args.slam_preset,
            imitate=args.imitate,
            imitation_steps=args.imitation_steps,
            imitation_epochs=args.imitation_epochs,
            imitation_rounds=args.imitation_rounds,
            frontier_cue=args.frontier_cue,
            shield=args.shield,
            imitate_config=args.imitate_config,
        )
    except ValueError as err:  # bad settings: named, no traceback
        print(f"error: {err}", file=sys.stderr)
        return 2
    config = json.loads((args.out / "train_config.json").read_text())
    print(
        f"saved {path}: {config['trained_timesteps']} steps in {config['wall_s']:.0f} s "
        f"({config['steps_per_s']:.1f} steps/s)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
