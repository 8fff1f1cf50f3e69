"""The worker's side of a run: uav-run's outcome -> done, crashed, hung or interrupted, with its logs.

A stand-in ``uav-run`` (a shell script first on PATH) plays each outcome, so the runner's own process handling
(its budget, stopping the whole process group, reading what the run left) runs for real in the unit tier. The
real uav-run on real workers is tests/e2e/campaigns.
"""

from __future__ import annotations

import json
import os
import stat
import time
from pathlib import Path
from typing import Any

import pytest

from uav_campaigns.shell.runner import classify, execute_run

SCRIPTS = {
    "done": """#!/bin/sh
run_dir="$3"
echo "flying"
printf '{"final": true, "stop_reason": "time_limit", "time": {"duration_s": 20.0}}' > "$run_dir/metrics.json"
printf '{"real_time_factor": 3.1}' > "$run_dir/pace.json"
""",
    "crash": """#!/bin/sh
echo "the sim bridge died: EGL not available" >&2
exit 1
""",
    "hang": """#!/bin/sh
echo "waiting for a grant that never comes"
trap 'echo "interrupted: stopping the run"; exit 130' INT
while true; do sleep 0.1; done
""",
    "bad": """#!/bin/sh
echo "uav-run: scenario.yaml: 'stop' has unknown key(s) 'time_limit'" >&2
exit 2
""",
}


def job(tmp: Path, **extra: Any) -> dict[str, Any]:
    return {
        "campaign": "t",
        "campaign_id": "abc",
        "key": "k1",
        "try": 1,
        "label": "a/s1/r0",
        "config_hash": "f" * 64,
        "scenario": {"name": "t-a-s1-r0", "mission": "loiter", "world": {"config": "/nowhere/w.yaml"}},
        "world_text": "name: w\nseed: 1\n",
        "run_dir": str(tmp / "out" / "runs" / "a" / "s1-r0-t1"),
        "out_dir": str(tmp / "out"),
        "budget_s": 60.0,
        **extra,
    }


@pytest.fixture
def stand_in(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    def use(kind: str) -> None:
        bin_dir = tmp_path / f"bin_{kind}"
        bin_dir.mkdir()
        script = bin_dir / "uav-run"
        script.write_text(SCRIPTS[kind])
        script.chmod(script.stat().st_mode | stat.S_IEXEC)
        monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "campaign.json").write_text(json.dumps({"campaign_id": "abc"}))
    return use


def test_a_finished_run_is_done_and_its_inputs_are_in_its_folder(tmp_path: Path, stand_in) -> None:  # type: ignore[no-untyped-def]
    stand_in("done")
    events: list[dict[str, Any]] = []
    res = execute_run(job(tmp_path), on_event=events.append, poll_s=0.05)
    assert (res["status"], res["reason"], res["exit_code"]) == ("done", "", 0)
    assert res["sim_s"] == 20.0
    assert res["shared"] is True
    run_dir = Path(res["run_dir"])
    assert run_dir == tmp_path / "out" / "runs" / "a" / "s1-r0-t1"
    assert (run_dir / "world.yaml").read_text() == "name: w\nseed: 1\n"
    scenario = (run_dir / "campaign_scenario.yaml").read_text()
    assert f"config: {run_dir / 'world.yaml'}" in scenario  # the run is self-contained
    assert [e["event"] for e in events] == ["started"]
    # a second try of the same job (its worker died) never reuses the folder
    again = execute_run(job(tmp_path), poll_s=0.05)
    assert again["run_dir"] == str(run_dir) + ".2"


def test_a_crash_and_a_bad_scenario_are_failures_with_the_log(tmp_path: Path, stand_in) -> None:  # type: ignore[no-untyped-def]
    stand_in("crash")
    res = execute_run(job(tmp_path), poll_s=0.05)
    assert (res["status"], res["reason"], res["exit_code"]) == ("failed", "crashed", 1)
    assert "EGL not available" in res["log_tail"]


def test_a_bad_scenario_is_not_worth_retrying(tmp_path: Path, stand_in) -> None:  # type: ignore[no-untyped-def]
    stand_in("bad")
    res = execute_run(job(tmp_path), poll_s=0.05)
    assert (res["status"], res["reason"]) == ("failed", "bad_config")
    assert "'time_limit'" in res["log_tail"]


def test_a_hung_run_is_stopped_at_its_budget(tmp_path: Path, stand_in) -> None:  # type: ignore[no-untyped-def]
    stand_in("hang")
    t0 = time.monotonic()
    res = execute_run(job(tmp_path, budget_s=1.0, grace_s=0.0, int_timeout_s=5.0), poll_s=0.05)
    assert time.monotonic() - t0 < 8.0
    assert (res["status"], res["reason"]) == ("failed", "hung")
    assert "interrupted: stopping the run" in res["log_tail"]  # it got SIGINT first, as uav-run wants


def test_a_stopped_campaign_interrupts_the_run(tmp_path: Path, stand_in) -> None:  # type: ignore[no-untyped-def]
    stand_in("hang")
    t0 = time.monotonic()
    res = execute_run(job(tmp_path), should_stop=lambda: time.monotonic() - t0 > 0.5, poll_s=0.05)
    assert (res["status"], res["reason"]) == ("interrupted", "campaign stopped")
    before = execute_run(job(tmp_path), should_stop=lambda: True)
    assert before["status"] == "interrupted"
    assert "before the run started" in before["reason"]


def test_without_the_campaign_directory_the_run_folder_comes_back_as_an_archive(tmp_path: Path, stand_in) -> None:  # type: ignore[no-untyped-def]
    stand_in("done")
    res = execute_run(job(tmp_path, transfer="always"), poll_s=0.05)
    assert res["status"] == "done"
    assert res["shared"] is False
    assert isinstance(res["archive"], bytes)
    assert not Path(res["run_dir"]).exists()  # the worker's temporary folder is gone


@pytest.mark.parametrize(
    ("rc", "metrics", "hung", "stopped", "expected"),
    [
        (0, {"final": True, "stop_reason": "time_limit"}, False, False, ("done", "")),
        (0, {"final": True, "stop_reason": "collision"}, False, False, ("done", "")),  # a result, not a failure
        (0, {"final": True, "stop_reason": "wall_timeout"}, False, False, ("failed", "hung")),
        (1, {"final": True, "stop_reason": "node_died"}, False, False, ("failed", "crashed")),
        (0, None, False, False, ("failed", "no_metrics")),
        (3, None, False, False, ("failed", "unavailable")),
        (-9, None, False, False, ("failed", "killed (exit -9)")),
        (130, None, True, False, ("failed", "hung")),
        (130, None, False, True, ("interrupted", "campaign stopped")),
    ],
)
def test_classify(
    rc: int, metrics: dict[str, Any] | None, hung: bool, stopped: bool, expected: tuple[str, str]
) -> None:
    assert classify(rc, metrics, hung=hung, stopped=stopped) == expected
