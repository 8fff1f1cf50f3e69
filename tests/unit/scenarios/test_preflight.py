"""What the sim bridge or the SITL would refuse is a configuration error before a run starts (uav-run, uav-campaign),
not a run dying seconds into its launch."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from helpers.paths import REPO

from uav_scenarios.core.config import load_scenario
from uav_scenarios.errors import ScenarioConfigError
from uav_scenarios.shell.preflight import check_node_settings, check_runs

LOITER = REPO / "config" / "scenarios" / "loiter.yaml"


def _scenario(tmp_path: Path, node_params: dict[str, object]) -> Path:
    data = yaml.safe_load(LOITER.read_text())
    data.setdefault("node_params", {}).update(node_params)
    data["world"] = {"config": str(REPO / "config" / "worlds" / "small.yaml"), "size_m": 400.0}
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_shipped_scenarios_pass() -> None:
    scenarios = sorted((REPO / "config" / "scenarios").glob("*.yaml"))
    assert len(scenarios) >= 3
    assert check_runs((p.name, load_scenario(p)) for p in scenarios) >= 1


def test_a_camera_mount_in_the_bridge_settings_is_refused_naming_file_and_key(tmp_path: Path) -> None:
    path = _scenario(tmp_path, {"sim_bridge": {"cameras": {"nadir": {"mount": {"rpy_deg": [0, 90, 0]}}}}})
    with pytest.raises(
        ScenarioConfigError, match=r"sim bridge would refuse.*cameras\.nadir\.mount.*config/robot\.yaml"
    ):
        check_node_settings(load_scenario(path))
    with pytest.raises(ScenarioConfigError, match=str(path)):
        check_node_settings(load_scenario(path))


def test_an_unknown_bridge_key_is_refused(tmp_path: Path) -> None:
    path = _scenario(tmp_path, {"sim_bridge": {"cameras": {"forward": {"hfov": 90.0}}}})
    with pytest.raises(ScenarioConfigError, match="hfov"):
        check_node_settings(load_scenario(path))


def test_a_sitl_setting_it_would_refuse_is_refused_naming_the_key(tmp_path: Path) -> None:
    path = _scenario(tmp_path, {"sitl": {"battery": {"capacity_mahh": 100}}})
    with pytest.raises(ScenarioConfigError, match=r"node_params\.sitl.*capacity_mahh"):
        check_node_settings(load_scenario(path), where="arm 'x'")
    good = _scenario(tmp_path, {"sitl": {"battery": {"capacity_mah": 2000}}})
    check_node_settings(load_scenario(good))


def test_many_runs_check_each_distinct_setting_once(tmp_path: Path) -> None:
    scenario = load_scenario(_scenario(tmp_path, {}))
    assert check_runs([("a", scenario), ("b", scenario), ("c", scenario)]) == 1


def test_uav_run_refuses_before_making_anything(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from uav_scenarios.cli.run import main  # noqa: PLC0415

    path = _scenario(tmp_path, {"sim_bridge": {"cameras": {"nadir": {"mount": {"rpy_deg": [0, 90, 0]}}}}})
    runs = tmp_path / "runs"
    runs.mkdir()
    assert main([str(path), "--runs-dir", str(runs)]) == 2
    assert "cameras.nadir.mount" in capsys.readouterr().err
    assert not list(runs.iterdir())


def _learned(tmp_path: Path, model: str) -> Path:
    data = yaml.safe_load(LOITER.read_text())
    data["world"] = {"config": str(REPO / "config" / "worlds" / "small.yaml"), "size_m": 400.0}
    data["perception"] = {"detector": "learned", "model": model, "camera": "forward"}
    path = tmp_path / "learned.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_learned_detectors_model_is_loaded_before_anything_starts(tmp_path: Path) -> None:
    """A missing, corrupt or wrong-shape model is a configuration error of the run (exit 2 from uav-run), naming
    the scenario and the model file; a good one (relative to the scenario file) passes."""
    from helpers.onnx_models import constant_detector  # noqa: PLC0415

    path = _learned(tmp_path, "models/missing.onnx")
    with pytest.raises(
        ScenarioConfigError, match=rf"{path}: perception.detector learned: .*models/missing.onnx: no such"
    ):
        check_node_settings(load_scenario(path))
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "corrupt.onnx").write_bytes(b"\x00" * 64)
    with pytest.raises(ScenarioConfigError, match=r"corrupt\.onnx: not a loadable ONNX model"):
        check_node_settings(load_scenario(_learned(tmp_path, "models/corrupt.onnx")))
    constant_detector(tmp_path / "models" / "wrong.onnx", [[1, 2, 3, 4, 5, 6]], output_shape=[1, 6])
    with pytest.raises(ScenarioConfigError, match=r"wrong.onnx: output 'output0' is tensor\(float\) \[1, 6\]"):
        check_node_settings(load_scenario(_learned(tmp_path, "models/wrong.onnx")))
    constant_detector(tmp_path / "models" / "good.onnx", [[100, 100, 20, 40, 0.9, 0.1]])
    check_node_settings(load_scenario(_learned(tmp_path, "models/good.onnx")))
