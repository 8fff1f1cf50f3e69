"""Causal lockstep (docs/lockstep.md): the same scenario and seed give the same run, bit for bit, whatever the
machine is doing: alone, beside a CPU hog on every core, and two runs side by side.

The scenario is small_lawnmower.yaml: search and rescue in the small world in the stress_all environment (shadows,
exposure, noise, motion blur, defocus, vignetting, JPEG, 2 % dropped frames and 50 ms of latency, all seeded), with
the map server, the geolocator, the tracker, the mission manager's confirmation and the scorer in the loop. What is
compared: every metric, the scorer's whole time series, the ground-truth trajectory and what the detector and the
controller published, message by message, from the recorded bags.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest
from helpers.procs import artifacts_dir
from helpers.runs import cpu_hogs, metrics, metrics_differences, start_run, uav_run, wait_run

pytestmark = pytest.mark.slow
HERE = Path(__file__).resolve().parent
SCENARIO = HERE / "small_lawnmower.yaml"
GROUP = "determinism_e2e"
RUNS: dict[str, Path] = {}


def run(name: str) -> Path:
    run_dir, _ = uav_run(SCENARIO, name, "--name", "det", group=GROUP)
    RUNS[name] = run_dir
    return run_dir


#: Recorded topics published by the simulator and the nodes in the loop, compared message by message (raw bytes:
#: every field, stamps and header sequence numbers included). Left out: /scenario/status and /scenario/metrics
#: (they carry the measured real-time factor) and /map_server/insert_stats (it times each insertion): wall time,
#: not part of the run.
COMPARED = (
    "/uav/ground_truth/odom",
    "/uav/battery",
    "/uav/controller/state",
    "/autonomy/goal",
    "/autonomy/goal_reason",
    "/autonomy/path",
    "/detections/ground_truth",
    "/geolocator/detections",
    "/scenario/tracks",
    "/sim/object_states",
)


def signature(run_dir: Path) -> dict[str, Any]:
    """What must be identical between two runs: the time series and, per compared topic, every recorded message."""
    from rosbags.highlevel import AnyReader  # noqa: PLC0415

    out: dict[str, Any] = {"timeseries": (run_dir / "timeseries.csv").read_text()}
    with AnyReader([run_dir / "run.bag"]) as reader:
        for topic in COMPARED:
            conns = [c for c in reader.connections if c.topic == topic]
            out[topic] = [bytes(raw) for _c, _t, raw in reader.messages(connections=conns)]
    return out


def assert_same(a: Path, b: Path) -> None:
    differ = metrics_differences(a, b)
    assert not differ, f"{a.name} and {b.name}: metrics differ: {dict(list(differ.items())[:10])}"
    sa, sb = signature(a), signature(b)
    for key in sa:
        if sa[key] != sb[key]:
            n = len(sa[key]) if isinstance(sa[key], list) else 1
            first = next((i for i, (x, y) in enumerate(zip(sa[key], sb[key], strict=False)) if x != y), None)
            pytest.fail(
                f"{a.name} and {b.name}: the recorded {key} differ ({n} against "
                f"{len(sb[key]) if isinstance(sb[key], list) else 1} messages, first difference at {first})"
            )


def test_a_run_is_a_function_of_its_scenario_alone() -> None:
    reference = run("alone")
    m = metrics(reference)
    assert m["stop_reason"] in ("target_found", "time_limit")
    assert m["map_input"]["clouds_inserted"] > 100
    # nothing dropped for being late (the camera's own seeded drops leave incomplete frames: unsynchronized)
    assert m["map_input"]["dropped_queue_full"] == 0, m["map_input"]
    assert m["map_input"]["dropped_no_transform"] == 0, m["map_input"]
    sig = signature(reference)
    assert len(sig["/uav/ground_truth/odom"]) > 100
    assert sig["/geolocator/detections"]
    assert sig["/autonomy/path"]
    with cpu_hogs(2):
        assert_same(reference, run("beside_cpu_hogs"))


def test_two_runs_side_by_side_equal_the_one_alone() -> None:
    if "alone" not in RUNS:
        run("alone")
    procs = {}
    for name in ("side_a", "side_b"):
        run_dir = artifacts_dir() / GROUP / name
        procs[name] = (start_run(SCENARIO, run_dir, name, "--name", "det"), run_dir)
    errors: list[BaseException] = []

    def wait(name: str) -> None:
        try:
            wait_run(procs[name][0], name, 420.0)
        except BaseException as err:
            errors.append(err)

    waiters = [threading.Thread(target=wait, args=(n,)) for n in procs]
    for t in waiters:
        t.start()
    for t in waiters:
        t.join()
    if errors:
        raise errors[0]
    for _proc, run_dir in procs.values():
        assert_same(RUNS["alone"], run_dir)
