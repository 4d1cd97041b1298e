"""benchmarks/bench_icp_batch.py keeps pace with the filter's ``align_many`` call.

The script records the filter's calls by replacing ``align_many``; when the filter's
call gained a keyword (``prior_weight``) the recording wrapper refused it and the
benchmark crashed. Here it records a short route and replays the calls both ways.
"""

import importlib.util
from pathlib import Path

from vslam_gym.slam import icp

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_icp_batch.py"
_spec = importlib.util.spec_from_file_location("bench_icp_batch", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_recorded_calls_replay_alike_side_by_side_and_one_at_a_time():
    calls = bench.record("single_landmark", 0)
    assert len(calls) > 20  # scans with candidate landmarks along the route
    calls = calls[:10]
    lines = [[icp.line_geometry(m) for m in call[1]] for call in calls]
    single = [bench.one_at_a_time(c, g) for c, g in zip(calls, lines, strict=True)]
    batch = [bench.side_by_side(c, g) for c, g in zip(calls, lines, strict=True)]
    assert [len(r) for r in single] == [len(r) for r in batch] == [len(c[1]) for c in calls]
    # the two ways differ only by round-off: nearly every alignment ends alike
    total = sum(len(r) for r in single)
    assert sum(bench.differ(a, b) for a, b in zip(single, batch, strict=True)) <= 0.1 * total
