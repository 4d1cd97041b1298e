"""Paired comparison of two evaluations (``vslam-gym compare``).

Two configurations of the estimator, or two agents, are best compared on the same
seeds, episodes or logs: the per-run differences cancel what the runs share (the world,
the route, the log), so a smaller difference shows. This module pairs the runs of two
outputs of ``vslam-gym evaluate``, ``vslam-gym replay`` or
``agents/evaluate_agents.py`` by their seed (or, for a tree of single replays, by their
directory) and reports, for each metric, both means, the mean difference, the paired
t statistic and how many pairs went either way.

The estimator amplifies round-off: the same configuration run on scans perturbed in
their last bits (``--range-perturbation 1e-15``) moves a run's position ATE by about 1
cm (docs/measurements.md, "Session 38"). Pairing does not remove that part of the
spread, so a paired t near 1 is no evidence either way; compare a configuration with a
round-off sample of itself to see how large the noise is.

Usage::

    vslam-gym compare BASE OTHER [--metrics ate_rmse_m nees_mean ...]

``BASE`` and ``OTHER`` are a ``metrics.json`` file or a directory: one holding a
``metrics.json``, or a tree of output directories (for example one replay per log),
each run keyed by its directory relative to the tree.
"""

from __future__ import annotations

import argparse
import difflib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

METRICS_FILE = "metrics.json"
"""The file every evaluation command writes its metrics to."""

RUN_LISTS = ("per_seed", "per_episode")
"""Keys of a ``metrics.json`` that hold one metrics mapping per run (with its ``seed``)."""

DEFAULT_METRICS = (
    "ate_rmse_m",
    "ate_m",
    "final_error_m",
    "heading_rmse_rad",
    "coverage",
    "nees_mean",
    "nees_in_band_fraction",
    "association_precision",
    "duplicate_fraction",
    "landmarks",
    "collisions",
    "return",
    "step_ms_median",
)
"""Metrics compared when none are named (those the two outputs have)."""


@dataclass(frozen=True)
class MetricComparison:
    """One metric over the paired runs of two evaluations.

    Attributes:
        metric: the ``metrics.json`` key.
        pairs: runs of both evaluations with a finite value of the metric.
        base_mean: mean over those runs of the base evaluation.
        other_mean: mean over the same runs of the other evaluation.
        difference: ``other_mean - base_mean``.
        paired_t: the mean per-run difference over its standard error (NaN with fewer
            than two pairs; +-inf when every pair differs by the same amount).
        lower: pairs where the other evaluation's value is lower.
        higher: pairs where it is higher.
        equal: pairs where both are equal.
    """

    metric: str
    pairs: int
    base_mean: float
    other_mean: float
    difference: float
    paired_t: float
    lower: int
    higher: int
    equal: int


def _numeric(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _runs_of_file(path: Path, prefix: str) -> dict[str, dict[str, Any]]:
    """The runs of one ``metrics.json``, keyed ``prefix`` plus the seed (if any)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read {path}: {err}") from err
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object of metrics, got {type(data).__name__}")
    for key in RUN_LISTS:
        if key in data:
            rows = data[key]
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                raise ValueError(f"{path}: {key!r} must be a list of metrics objects")
            runs: dict[str, dict[str, Any]] = {}
            for i, row in enumerate(rows):
                name = f"seed {row['seed']}" if "seed" in row else f"run {i}"
                name = f"{prefix}/{name}" if prefix else name
                if name in runs:
                    raise ValueError(f"{path}: {name!r} appears twice in {key!r}")
                runs[name] = row
            return runs
    return {prefix or "run": data}  # one run (a single replay)


def load_runs(path: str | Path) -> dict[str, dict[str, Any]]:
    """Per-run metrics of an evaluation output, keyed by run.

    Args:
        path: a ``metrics.json`` (its ``per_seed`` or ``per_episode`` runs keyed ``seed
            S``; a file without them is one run, keyed ``run``, which
            :func:`compare_runs` pairs by its ``seed`` with a multi-seed output), a
            directory holding one, or a
            directory whose subdirectories hold them (searched down to the first
            ``metrics.json`` of each branch; runs keyed by their directory relative to
            ``path``, plus ``/seed S`` for a file of several seeds).

    Raises:
        ValueError: no ``metrics.json`` found, or one that is not a metrics object.
    """
    path = Path(path)
    if path.is_file():
        return _runs_of_file(path, "")
    if not path.is_dir():
        raise ValueError(f"{path}: no such file or directory")
    if (path / METRICS_FILE).is_file():
        return _runs_of_file(path / METRICS_FILE, "")
    runs: dict[str, dict[str, Any]] = {}
    pending = sorted(p for p in path.iterdir() if p.is_dir())
    while pending:
        directory = pending.pop(0)
        if (directory / METRICS_FILE).is_file():
            runs.update(
                _runs_of_file(directory / METRICS_FILE, directory.relative_to(path).as_posix())
            )
        else:
            pending = sorted(p for p in directory.iterdir() if p.is_dir()) + pending
    if not runs:
        raise ValueError(f"{path}: no {METRICS_FILE} in it or below it")
    return runs


def _paired_t(diff: np.ndarray) -> float:
    if diff.size < 2:
        return math.nan
    mean = float(diff.mean())
    spread = float(diff.std(ddof=1))
    if spread == 0.0:
        return 0.0 if mean == 0.0 else math.copysign(math.inf, mean)
    return mean / (spread / math.sqrt(diff.size))


def _seeded(
    runs: Mapping[str, Mapping[str, Any]], against: Mapping[str, Mapping[str, Any]]
) -> Mapping[str, Mapping[str, Any]]:
    """A lone run (key ``run``) keyed by its seed when ``against`` is keyed by seeds.

    A single replay (``--seed 3``) then pairs with that seed of a multi-seed one.
    """
    lone = runs.get("run")
    if len(runs) != 1 or lone is None or "run" in against or not _numeric(lone.get("seed")):
        return runs
    return {f"seed {lone['seed']}": lone}


def compare_runs(
    base: Mapping[str, Mapping[str, Any]],
    other: Mapping[str, Mapping[str, Any]],
    metrics: Sequence[str] | None = None,
) -> list[MetricComparison]:
    """Compare two evaluations run by run (the runs both have, paired by key).

    Args:
        base: per-run metrics (:func:`load_runs`) of the reference evaluation.
        other: the same of the evaluation compared with it.
        metrics: keys to compare; None: those of :data:`DEFAULT_METRICS` that both
            have (every shared numeric key when they have none of them).

    Raises:
        ValueError: no run in common, a named metric that is not numeric in some paired
            run of either, or nothing to compare.
    """
    base, other = _seeded(base, other), _seeded(other, base)
    keys = [k for k in base if k in other]
    if not keys:
        raise ValueError(
            f"the two evaluations have no run in common (base: {sorted(base)[:5]}, "
            f"other: {sorted(other)[:5]})"
        )

    def shared(metric: str) -> bool:
        return all(_numeric(base[k].get(metric)) and _numeric(other[k].get(metric)) for k in keys)

    if metrics is None:
        metrics = [m for m in DEFAULT_METRICS if shared(m)]
        if not metrics:
            first = base[keys[0]]
            metrics = sorted(m for m in first if m != "seed" and shared(m))
    else:
        absent = [m for m in metrics if not all(m in base[k] and m in other[k] for k in keys)]
        if absent:
            names = sorted({m for k in keys for m in (*base[k], *other[k])} - {"seed"})
            hints = [difflib.get_close_matches(m, names, n=1) for m in absent]
            hint = "".join(
                f"; {m!r}: did you mean {h[0]!r}?" for m, h in zip(absent, hints, strict=True) if h
            )
            raise ValueError(
                f"no metric {absent} in every paired run of both evaluations{hint} "
                f"(their metrics: {', '.join(names)})"
            )
        missing = [m for m in metrics if not shared(m)]
        if missing:
            raise ValueError(f"not a number in every paired run of both evaluations: {missing}")
    if not metrics:
        raise ValueError("the two evaluations share no numeric metric")
    out = []
    for metric in metrics:
        a = np.array([float(base[k][metric]) for k in keys])
        b = np.array([float(other[k][metric]) for k in keys])
        finite = np.isfinite(a) & np.isfinite(b)
        a, b = a[finite], b[finite]
        diff = b - a
        out.append(
            MetricComparison(
                metric=metric,
                pairs=int(a.size),
                base_mean=float(a.mean()) if a.size else math.nan,
                other_mean=float(b.mean()) if b.size else math.nan,
                difference=float(diff.mean()) if diff.size else math.nan,
                paired_t=_paired_t(diff),
                lower=int((diff < 0).sum()),
                higher=int((diff > 0).sum()),
                equal=int((diff == 0).sum()),
            )
        )
    return out


def format_comparison(comparisons: Sequence[MetricComparison]) -> str:
    """A Markdown table of :func:`compare_runs`'s result."""
    lines = [
        "| metric | pairs | base | other | other - base | paired t | lower / higher / equal |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in comparisons:
        lines.append(
            f"| {c.metric} | {c.pairs} | {c.base_mean:.4g} | {c.other_mean:.4g} | "
            f"{c.difference:+.4g} | {c.paired_t:+.2f} | {c.lower} / {c.higher} / {c.equal} |"
        )
    return "\n".join(lines)


def cmd_compare(args: argparse.Namespace) -> int:
    """Handler of ``vslam-gym compare``."""
    base, other = load_runs(args.base), load_runs(args.other)
    comparisons = compare_runs(base, other, args.metrics)
    paired = sum(1 for k in base if k in other)
    print(f"base: {args.base} ({len(base)} runs); other: {args.other} ({len(other)} runs)")
    print(f"{paired} runs paired by key; runs of only one side are left out")
    print(format_comparison(comparisons))
    if args.json:
        rows = [c.__dict__ for c in comparisons]
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


def add_compare_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``vslam-gym compare`` to the command line."""
    parser = subparsers.add_parser(
        "compare",
        help="compare two evaluations run by run (paired by seed or log)",
        description="Pair the runs of two outputs of vslam-gym evaluate, vslam-gym replay "
        "or agents/evaluate_agents.py by seed (or by directory, for a tree of replays) and "
        "print each metric's means, their difference, the paired t statistic and how many "
        "pairs went lower / higher. A paired t near 1 is within the estimator's round-off "
        "spread (compare a --range-perturbation 1e-15 sample of the base to see it).",
    )
    parser.add_argument("base", help="metrics.json, or a directory holding it or a tree of them")
    parser.add_argument("other", help="the same for the evaluation compared with the base")
    parser.add_argument(
        "--metrics",
        nargs="+",
        default=None,
        metavar="KEY",
        help="metrics.json keys to compare (default: the usual accuracy, consistency, map "
        "and timing metrics the two have)",
    )
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the rows as JSON")
    parser.set_defaults(handler=cmd_compare)
