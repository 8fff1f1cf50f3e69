"""The scenario's table of simulated faults agrees with what the SITL models (the compass and baro units included)."""

from __future__ import annotations

from pathlib import Path

from helpers.paths import REPO

from sitl.core.faults import MODELLED, FailureType, FailureUnit
from uav_scenarios.core.config import load_scenario
from uav_scenarios.core.faults import FAILURE_TYPE_CODES, FAILURE_UNIT_CODES, SIMULATED, fault_actions, not_simulated


def test_the_scenarios_simulated_faults_are_the_sitls_modelled_ones() -> None:
    by_code = {FailureUnit(FAILURE_UNIT_CODES[u]): u for u in SIMULATED}
    assert set(by_code) == set(MODELLED), "every unit the SITL models can be scripted, and only those"
    for unit, name in by_code.items():
        scripted = {FailureType(FAILURE_TYPE_CODES[t]) for t in SIMULATED[name]} | {FailureType.OK}
        assert scripted == MODELLED[unit], name
    for unit in ("mag", "baro"):
        for kind in ("off", "stuck", "garbage", "intermittent", "ok"):
            assert not_simulated(unit, kind) == ""
        assert "not simulated by the SITL" in not_simulated(unit, "wrong")


def test_a_scenario_scripts_compass_and_baro_faults(tmp_path: Path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(
        f"name: x\nmission: loiter\nworld: {{config: {REPO / 'config/worlds/default.yaml'}}}\n"
        "faults: [{at_s: 30, unit: baro, type: stuck, duration_s: 20}, {at_s: 40, unit: mag, type: off}]\n"
    )
    actions = fault_actions(load_scenario(path).faults)
    assert [(a.at_s, a.unit_code, a.type_code) for a in actions] == [
        (30.0, 3, 2),  # FAILURE_UNIT_SENSOR_BARO, STUCK
        (40.0, 2, 1),  # FAILURE_UNIT_SENSOR_MAG, OFF
        (50.0, 3, 0),  # the baro cleared (OK) 20 s later
    ]
