r"""Evaluation rollouts of a scripted agent or a saved PPO model on the exploration envs.

    python agents/evaluate_agents.py --agent frontier --env VSlam/Explore-v0 \
        --episodes 10 --seed 1000 --out runs/eval/frontier [--video] [--max-steps 500]

``--agent`` is ``random``, ``route`` (an oracle on the true pose), ``wall``, ``frontier``
or the path of a stable-baselines3 PPO model (``.zip``; it acts deterministically).
``--env`` is any registered exploration id. Episode ``i`` uses ``env.reset(seed=S + i)``:
on ``VSlam/Explore-v0`` the seed draws the world, so seeds ``S .. S + N - 1`` are the
held-out worlds of the evaluation. **Train on other seeds** (e.g. below 1000 when
evaluating on 1000-1019) so that no evaluation world was seen in training.

Per episode: coverage (fraction of the true obstacle boundary within 0.1 m of a
modelled object line, :func:`vslam_gym.exploration.coverage`, at the end), position
ATE (RMSE of ``info["slam_pose"]`` against ``info["pose"]``, no alignment), the mean
3-dof pose NEES (and of the position and the heading alone, ``nees_position_mean`` and
``nees_heading_mean``), collisions, the return (the wrapper's belief reward), steps, final
landmark count, the revisit matches fused (``loop_closures``) and their NEES against the
true pose (``loop_match_nees_mean`` and ``_median``: 3 and 2.37 for consistent matches)
and throughput. Written to ``OUT``:

- ``metrics.json``: settings, per-episode metrics and their mean;
- ``steps.csv``: one row per step (step 0 is the reset): true and SLAM pose, reward and
  each reward term (``r_<term>``), coverage, collision, landmarks;
- ``metrics.md``: the table also printed on the terminal;
- ``episode.gif`` with ``--video``: the first episode, the belief drawn over the true
  world (the wrapper's ``render()``);
- ``logs/episode_<seed>.log.gz`` with ``--carmen-logs``: every episode's scans, true
  poses and wheel odometry as a Carmen log (:func:`vslam_gym.logs.write_carmen`), which
  ``vslam-gym replay LOG --odometry logged`` runs any SLAM configuration on: the same
  scans and odometry for every configuration, where closed-loop runs drive other paths.

The same arguments give the same numbers (timings apart): the world, the sensor noise
and the agents depend only on the seeds.

The functions :func:`run_agent_episode` and :func:`evaluate_agent` are the reusable part
(e.g. the final evaluation of a training script).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.append(str(Path(__file__).resolve().parent.parent))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import vslam_gym  # noqa: E402
from agents.scripted import SCRIPTED_AGENTS, Agent, make_agent  # noqa: E402
from vslam_gym.evaluation import (  # noqa: E402
    START_SCAN_MODES,
    json_object,
    json_safe,
    loop_match_nees,
    loop_match_summary,
    machine_description,
    name_or_mapping,
    nees_part_means,
    nees_summary,
    pose_nees,
    position_ate_rmse,
    progress_bar,
)
from vslam_gym.exploration import boundary_samples, coverage  # noqa: E402
from vslam_gym.logs import CarmenRecorder  # noqa: E402

gym.register_envs(vslam_gym)

TIMING_KEYS = ("wall_s", "steps_per_s", "env_steps_per_s")
"""Per-episode metrics that are timings (they differ between identical runs)."""

TABLE_COLUMNS = (
    ("coverage", "coverage", "{:.3f}"),
    ("ATE m", "ate_m", "{:.3f}"),
    ("NEES", "nees_mean", "{:.3g}"),
    ("coll", "collisions", "{:.2g}"),
    ("return", "return", "{:.2f}"),
    ("steps", "steps", "{:.0f}"),
    ("LMs", "landmarks", "{:.1f}"),
    ("dist m", "distance_m", "{:.1f}"),
    ("steps/s", "steps_per_s", "{:.1f}"),
)
"""``(header, metric key, format)`` of the summary table."""


@dataclass(frozen=True)
class EvaluationConfig:
    """Settings of the metrics and the video.

    Attributes:
        coverage_tolerance: distance [m] from a true boundary sample to a modelled object
            line within which the sample counts as covered.
        sample_spacing: spacing [m] of the true boundary samples.
        video_stride: keep every ``video_stride``-th frame in the GIF.
        video_fps: frames per second of the GIF at stride 1 (the control rate, 10 Hz).
    """

    coverage_tolerance: float = 0.1
    sample_spacing: float = 0.05
    video_stride: int = 2
    video_fps: float = 10.0

    def __post_init__(self) -> None:
        for name in ("coverage_tolerance", "sample_spacing", "video_stride", "video_fps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"EvaluationConfig.{name} must be > 0, got {value!r}")


# ---------------------------------------------------------------------------- agents


class PolicyAgent:
    """A trained stable-baselines3 policy as an agent (deterministic actions).

    Args:
        model: a loaded model (anything with ``predict(obs, deterministic=True)``) or
            the path of a saved PPO ``.zip``.
    """

    name = "ppo"

    def __init__(self, model: Any) -> None:
        if isinstance(model, str | Path):
            from stable_baselines3 import PPO  # only needed for saved models

            self.path = str(model)
            model = PPO.load(self.path, device="cpu")
        self.model = model

    def reset(
        self,
        env: gym.Env,
        obs: dict[str, np.ndarray],
        info: dict[str, Any],
        seed: int | None = None,
    ) -> None:
        """Nothing to reset (the policy is memoryless)."""

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        """The policy's deterministic action."""
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, dtype=np.float32)


def frontier_cue(agent: Agent) -> int:
    """Unknown lines in a policy's ``frontier`` observation (0: none, or not a policy)."""
    space = getattr(getattr(agent, "model", None), "observation_space", None)
    spaces = getattr(space, "spaces", None)
    if not spaces or "frontier" not in spaces:
        return 0
    return int(spaces["frontier"].shape[0]) // 4


def resolve_agent(
    agent: str | Path | Agent | Any,
    seed: int = 0,
    agent_config: Mapping[str, Any] | None = None,
) -> Agent:
    """An agent from a scripted name, a saved model path, a model or an agent.

    ``agent_config``: settings of a scripted agent by name (:func:`make_agent`).

    Raises:
        ValueError: for a name that is neither a scripted agent nor an existing file,
            or settings for anything but a scripted agent by name.
    """
    if isinstance(agent, str) and agent in SCRIPTED_AGENTS:
        return make_agent(agent, seed, agent_config)
    if agent_config:
        raise ValueError(f"agent settings apply to the scripted agents by name, not {agent!r}")
    if isinstance(agent, str | Path):
        if not Path(agent).is_file():
            raise ValueError(
                f"agent {str(agent)!r} is neither one of {sorted(SCRIPTED_AGENTS)} "
                "nor an existing model file"
            )
        return PolicyAgent(agent)
    if hasattr(agent, "act") and hasattr(agent, "reset"):
        return agent
    if hasattr(agent, "predict"):
        return PolicyAgent(agent)
    raise ValueError(f"cannot use {agent!r} as an agent")


# ---------------------------------------------------------------------------- one episode


@dataclass
class EpisodeResult:
    """One evaluated episode.

    Attributes:
        metrics: the episode's metrics (see the module docstring).
        rows: one dict per step (step 0: after reset) for ``steps.csv``.
        frames: rendered ``(H, W, 3)`` uint8 frames (only with ``render=True``).
    """

    metrics: dict[str, Any]
    rows: list[dict[str, Any]] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)


def _row(step: int, info: Mapping[str, Any], reward: float, cover: float) -> dict[str, Any]:
    pose, slam = info["pose"], info["slam_pose"]
    row = {
        "step": step,
        "true_x": float(pose[0]),
        "true_y": float(pose[1]),
        "true_theta": float(pose[2]),
        "slam_x": float(slam[0]),
        "slam_y": float(slam[1]),
        "slam_theta": float(slam[2]),
        "reward": float(reward),
    }
    for name, value in info.get("rewards", {}).items():
        row[f"r_{name}"] = float(value)
    row.update(
        coverage=float(cover), collision=int(bool(info["collision"])), landmarks=info["landmarks"]
    )
    return row


def run_agent_episode(
    env: gym.Env,
    agent: Agent,
    seed: int,
    max_steps: int | None = None,
    config: EvaluationConfig | None = None,
    render: bool = False,
    on_step: Callable[[int], None] | None = None,
    carmen_log: str | Path | None = None,
) -> EpisodeResult:
    """Run one episode of ``agent`` on a SLAM-wrapped env and measure it.

    Args:
        env: an exploration env (``gym.make("VSlam/Explore...-v0")``); needs
            ``render_mode="rgb_array"`` for ``render=True``.
        agent: the agent (reset here with the episode seed).
        seed: ``env.reset(seed=seed)``.
        max_steps: stop after this many steps (else at termination or truncation).
        config: coverage tolerance and sample spacing.
        render: keep a frame per step (``env.render()``) in the result.
        on_step: called with the step number after every step (progress bars).
        carmen_log: write the episode's scans, true poses and wheel odometry to this
            Carmen log (``.log`` or ``.log.gz``; :class:`vslam_gym.logs.CarmenRecorder`).

    Returns:
        The metrics, the per-step rows and the frames.
    """
    cfg = config if config is not None else EvaluationConfig()
    obs, info = env.reset(seed=seed)
    agent.reset(env, obs, info, seed=seed)
    samples = boundary_samples(env.unwrapped.world, cfg.sample_spacing)

    tolerance = cfg.coverage_tolerance
    rows = [_row(0, info, 0.0, coverage(samples, env.get_wrapper_attr("belief"), tolerance))]
    frames = [env.render()] if render else []
    recorder = None
    if carmen_log is not None:
        sim = env.unwrapped
        recorder = CarmenRecorder(
            info["bearings"], sim.lidar_spec.max_range, sim.physics_config.control_period
        )
        recorder.add(sim.scan.ranges, info["pose"], info["odom_pose"])
    true_poses, slam_poses, covariances = [info["pose"]], [info["slam_pose"]], []
    match_nees: list[float] = []  # of each fused revisit match
    total, collisions, distance, env_seconds = 0.0, 0, 0.0, 0.0
    terminated = truncated = False
    step = 0
    start = time.perf_counter()
    while not (terminated or truncated) and (max_steps is None or step < max_steps):
        action = agent.act(obs, info)
        tick = time.perf_counter()
        obs, reward, terminated, truncated, info = env.step(action)
        env_seconds += time.perf_counter() - tick
        step += 1
        total += float(reward)
        collisions += int(bool(info["collision"]))
        distance += float(np.hypot(*(info["pose"][:2] - true_poses[-1][:2])))
        true_poses.append(info["pose"])
        slam_poses.append(info["slam_pose"])
        covariances.append(info["slam_pose_cov"])
        belief = env.get_wrapper_attr("belief")
        if (fused := loop_match_nees(belief, info["pose"])) is not None:
            match_nees.append(fused)
        rows.append(_row(step, info, reward, coverage(samples, belief, tolerance)))
        if recorder is not None:
            recorder.add(env.unwrapped.scan.ranges, info["pose"], info["odom_pose"])
        if render:
            frames.append(env.render())
        if on_step is not None:
            on_step(step)
    wall = time.perf_counter() - start
    if recorder is not None:
        recorder.write(carmen_log)
    true_arr, slam_arr = np.asarray(true_poses), np.asarray(slam_poses)
    covs = np.asarray(covariances).reshape(-1, 3, 3)
    parts = nees_part_means(slam_arr[1:], covs, true_arr[1:])
    metrics = {
        "seed": int(seed),
        "world": env.unwrapped.world.name,
        "steps": step,
        "terminated": bool(terminated),
        "truncated": bool(truncated),
        "coverage": rows[-1]["coverage"],
        "ate_m": position_ate_rmse(slam_arr, true_arr),
        "nees_mean": nees_summary(pose_nees(slam_arr[1:], covs, true_arr[1:]))["nees_mean"],
        **parts,
        "collisions": collisions,
        "return": total,
        "landmarks": int(info["landmarks"]),
        "loop_closures": len(match_nees),
        **loop_match_summary(np.array(match_nees)),
        "distance_m": distance,
        "boundary_samples": len(samples.points),
        "wall_s": wall,
        "steps_per_s": step / wall if wall > 0 else math.nan,
        "env_steps_per_s": step / env_seconds if env_seconds > 0 else math.nan,
    }
    for key in ("targets_reached", "targets_abandoned"):
        if hasattr(agent, key):
            metrics[key] = int(getattr(agent, key))
    return EpisodeResult(metrics, rows, frames)


# ---------------------------------------------------------------------------- many episodes


def mean_metrics(per_episode: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Mean of every numeric metric over episodes (NaN values skipped)."""
    out: dict[str, float] = {}
    if not per_episode:
        return out
    for key, value in per_episode[0].items():
        if isinstance(value, bool) or not isinstance(value, int | float) or key == "seed":
            continue
        values = np.array([float(m[key]) for m in per_episode if m.get(key) is not None])
        values = values[np.isfinite(values)]
        out[key] = float(values.mean()) if values.size else math.nan
    return out


def format_table(result: Mapping[str, Any]) -> str:
    """A markdown table: one row per episode and the mean."""

    def cell(value: Any, fmt: str) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return "-"
        return fmt.format(value)

    header = ["seed", *(name for name, _, _ in TABLE_COLUMNS)]
    rows = [
        [str(m["seed"]), *(cell(m.get(key), fmt) for _, key, fmt in TABLE_COLUMNS)]
        for m in result["per_episode"]
    ]
    mean = result["mean"]
    rows.append(["**mean**", *(cell(mean.get(key), fmt) for _, key, fmt in TABLE_COLUMNS)])
    n = len(result["per_episode"])
    title = (
        f"agent `{result['agent']}` on `{result['env_id']}` (reward "
        f"{result.get('reward', 'registered')}), {n} episode(s), seeds "
        f"{result['seed']}..{result['seed'] + n - 1}"
    )
    lines = [title, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _write_csv(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    columns: list[str] = []
    for row in rows:
        columns += [key for key in row if key not in columns]
    terms = [c for c in columns if c.startswith("r_")]
    head = [
        c for c in columns if c not in terms and c not in ("coverage", "collision", "landmarks")
    ]
    ordered = head + terms + ["coverage", "collision", "landmarks"]
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=ordered, restval="")
        writer.writeheader()
        writer.writerows(rows)


def save_gif(frames: Sequence[np.ndarray], path: Path, config: EvaluationConfig) -> None:
    """Write frames (``(H, W, 3)`` uint8) as a looping GIF with Pillow."""
    from PIL import Image  # only the video needs Pillow

    kept = list(frames[:: config.video_stride])
    if not kept:
        return
    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in kept]
    duration = int(round(1000.0 * config.video_stride / config.video_fps))
    images[0].save(path, save_all=True, append_images=images[1:], duration=duration, loop=0)


def evaluate_agent(
    agent: str | Path | Agent | Any,
    env_id: str = vslam_gym.EXPLORE_ID,
    episodes: int = 10,
    seed: int = 1000,
    out_dir: str | Path | None = None,
    video: bool = False,
    max_steps: int | None = None,
    config: EvaluationConfig | None = None,
    progress: bool = True,
    env_kwargs: Mapping[str, Any] | None = None,
    reward: str | None = None,
    shield: bool = False,
    slam_config: str | Mapping[str, Any] | None = None,
    start_scan: str | None = None,
    carmen_logs: bool = False,
    agent_config: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Evaluate an agent over ``episodes`` seeded episodes; optionally write the files.

    Args:
        agent: ``"random"``, ``"route"``, ``"wall"``, ``"frontier"``, a PPO ``.zip``
            path, a loaded model, or an agent object.
        env_id: a registered exploration id.
        episodes: number of episodes; episode ``i`` resets with ``seed + i``.
        seed: first seed (also the random agent's seed).
        out_dir: where to write ``metrics.json``, ``steps.csv``, ``metrics.md`` (and
            ``episode.gif``); nothing is written when None.
        video: record the first episode as a GIF (needs ``out_dir``).
        max_steps: episode length; default the registration's ``max_episode_steps``.
        config: metric and video settings.
        progress: show a tqdm progress bar over steps.
        env_kwargs: extra keyword arguments of ``gym.make``.
        reward: a reward preset of the wrapper (``default``, ``d_opt``, ``coverage``;
            :func:`vslam_gym.explore_spec`) instead of the registration's, e.g. the one a
            policy was trained with (only the return depends on it).
        shield: run every episode under the wrapper's speed shield
            (:class:`vslam_gym.shield.SpeedShield`), e.g. for a policy trained with it.
        slam_config: the wrapper's ``slam_config`` instead of the registration's (a
            preset name or a :meth:`SlamConfig.from_dict` mapping, e.g. ``{"filter":
            {"loop_closure": False}}``).
        start_scan: the wrapper's ``start_scan`` instead of the registration's
            (``"matcher"``): ``"map"`` or ``"none"`` (the behaviour before session 33).
        carmen_logs: write every episode as ``out_dir/logs/episode_<seed>.log.gz``
            (:func:`run_agent_episode`'s ``carmen_log``; needs ``out_dir``).
        agent_config: settings of a scripted agent named by ``agent``, e.g.
            ``{"reach_distance": 0.5}`` for ``frontier`` (:func:`agents.scripted.make_agent`).

    Returns:
        ``{"agent", "env_id", "seed", "episodes", "max_steps", "machine", "per_episode",
        "mean"}`` (the content of ``metrics.json``).
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if video and out_dir is None:
        raise ValueError("video=True needs an out_dir to write the GIF to")
    if carmen_logs and out_dir is None:
        raise ValueError("carmen_logs=True needs an out_dir to write the logs to")
    log_dir = Path(out_dir) / "logs" if carmen_logs and out_dir is not None else None
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
    cfg = config if config is not None else EvaluationConfig()
    runner = resolve_agent(agent, seed, agent_config)
    kwargs = dict(env_kwargs or {})
    if max_steps is not None:
        kwargs["max_episode_steps"] = int(max_steps)
    if video:
        kwargs["render_mode"] = "rgb_array"
    wrapper: dict[str, Any] = {} if reward is None else {"reward": reward}
    if shield:
        wrapper["shield"] = True
    if slam_config is not None:
        wrapper["slam_config"] = slam_config
    if start_scan is not None:
        wrapper["start_scan"] = start_scan
    cue = frontier_cue(runner)
    if cue:  # a policy trained with the frontier cue observes it again
        wrapper["observation"] = {"frontier_count": cue}
    spec = vslam_gym.explore_spec(env_id, **wrapper) if wrapper else env_id
    env = gym.make(spec, **kwargs)
    wrapped = env
    while isinstance(wrapped, gym.Wrapper) and not isinstance(wrapped, vslam_gym.SlamWrapper):
        wrapped = wrapped.env
    if not isinstance(wrapped, vslam_gym.SlamWrapper):
        env.close()
        raise ValueError(
            f"{env_id} has no SLAM wrapper: evaluate on an exploration id "
            f"({', '.join(i for i in gym.registry if i.startswith('VSlam/Explore'))})"
        )
    horizon = env.spec.max_episode_steps if env.spec is not None else None
    horizon = max_steps or horizon
    bar = progress_bar(episodes * horizon if horizon else None, "evaluate", progress, leave=True)
    per_episode, rows, frames = [], [], []
    try:
        for i in range(episodes):
            result = run_agent_episode(
                env,
                runner,
                seed + i,
                max_steps=horizon,
                config=cfg,
                render=video and i == 0,
                on_step=(lambda _step: bar.update(1)) if bar is not None else None,
                carmen_log=None if log_dir is None else log_dir / f"episode_{seed + i}.log.gz",
            )
            if bar is not None and horizon:
                bar.total -= horizon - result.metrics["steps"]  # an episode ended early
                bar.set_postfix(coverage=f"{result.metrics['coverage']:.3f}", refresh=True)
            per_episode.append(result.metrics)
            rows += [{"episode": i, "seed": seed + i, **row} for row in result.rows]
            if i == 0:
                frames = result.frames
    finally:
        env.close()
        if bar is not None:
            bar.close()
    name = agent if isinstance(agent, str | Path) else getattr(runner, "name", type(agent).__name__)
    summary = {
        "agent": str(name),
        "agent_config": dict(agent_config or {}),
        "env_id": env_id,
        "reward": reward or "registered",
        "shield": bool(shield),
        "slam_config": slam_config or "registered",
        "start_scan": start_scan or "registered",
        "carmen_logs": bool(carmen_logs),
        "seed": seed,
        "episodes": episodes,
        "max_steps": horizon,
        "coverage_tolerance_m": cfg.coverage_tolerance,
        "machine": machine_description(),
        "per_episode": per_episode,
        "mean": mean_metrics(per_episode),
    }
    summary = json_safe(summary)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(json.dumps(summary, indent=2) + "\n")
        _write_csv(out / "steps.csv", rows)
        (out / "metrics.md").write_text(format_table(summary) + "\n")
        if video:
            save_gif(frames, out / "episode.gif", cfg)
    return summary


# ---------------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser."""
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Train on other seeds than the evaluation's (held-out worlds).",
    )
    parser.add_argument(
        "--agent",
        required=True,
        help=f"one of {', '.join(SCRIPTED_AGENTS)}, or the path of a saved PPO .zip",
    )
    parser.add_argument(
        "--agent-config",
        default=None,
        type=_agent_config_argument,
        help='settings of a scripted agent as JSON, e.g. \'{"reach_distance": 0.5, '
        '"safety": {"margin": 0.2}}\' for frontier (agents/scripted.py: FrontierConfig, '
        "WallFollowerConfig, RouteAgentConfig)",
    )
    parser.add_argument("--env", default=vslam_gym.EXPLORE_ID, help="registered Explore id")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1000, help="episode i resets with seed+i")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--video", action="store_true", help="GIF of the first episode")
    parser.add_argument("--max-steps", type=int, default=None, help="episode length")
    parser.add_argument(
        "--reward",
        default=None,
        type=name_or_mapping,
        help="reward preset (default|d_opt|coverage) or JSON weights, e.g. "
        "'{\"collision\": 10}' (default: the registration's)",
    )
    parser.add_argument(
        "--shield",
        action="store_true",
        help="cap forward speed by the scan's free corridor (vslam_gym.shield)",
    )
    parser.add_argument(
        "--slam-config",
        default=None,
        type=name_or_mapping,
        help="SLAM preset name or JSON mapping over it (default: the registration's), "
        'e.g. \'{"filter": {"loop_closure": false}}\'',
    )
    parser.add_argument(
        "--start-scan",
        choices=START_SCAN_MODES,
        default=None,
        help="what the filter does with the scan of reset (default: the registration's, "
        "'matcher'); 'none' as before session 33",
    )
    parser.add_argument(
        "--carmen-logs",
        action="store_true",
        help="write every episode's scans, true poses and odometry to OUT/logs/"
        "episode_<seed>.log.gz (Carmen format; vslam-gym replay LOG --odometry logged)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _agent_config_argument(text: str) -> dict[str, Any]:
    """``--agent-config``: a JSON object (checked when the agent is made)."""
    return json_object(text, "--agent-config")


def training_differences(agent: str, args: argparse.Namespace) -> list[str]:
    """The training options of a saved model that this evaluation's options leave out.

    Reads ``train_config.json`` beside the model (written by ``agents/train_ppo.py``):
    its shield, SLAM preset and reward, when this evaluation runs without them (an
    evaluation uses the registration's unless told). Empty for a scripted agent or
    a model without that file.
    """
    path = Path(agent).parent / "train_config.json"
    if agent in SCRIPTED_AGENTS or not path.is_file():
        return []
    trained = json.loads(path.read_text())
    missing = []
    if trained.get("shield") and not args.shield:
        missing.append("--shield")
    preset = trained.get("slam_preset")
    if preset not in (None, "default") and args.slam_config is None:
        missing.append(f"--slam-config {preset}")
    reward = trained.get("reward")
    if reward not in (None, "default") and args.reward is None:
        missing.append(f"--reward '{json.dumps(reward)}'")
    return missing


def main(argv: Sequence[str] | None = None) -> int:
    """Run the evaluation, write the files, print the table."""
    args = build_parser().parse_args(argv)
    missing = training_differences(args.agent, args)
    if missing:
        print(
            f"note: {args.agent} was trained with {' '.join(missing)} "
            "(its train_config.json); this evaluation runs without: pass them to evaluate "
            "it as trained",
            file=sys.stderr,
        )
    try:
        result = evaluate_agent(
            args.agent,
            env_id=args.env,
            episodes=args.episodes,
            seed=args.seed,
            out_dir=args.out,
            video=args.video,
            max_steps=args.max_steps,
            progress=not args.no_progress,
            reward=args.reward,
            shield=args.shield,
            slam_config=args.slam_config,
            start_scan=args.start_scan,
            carmen_logs=args.carmen_logs,
            agent_config=args.agent_config,
        )
    except (ValueError, gym.error.Error) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
