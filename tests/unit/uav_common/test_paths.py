"""uav_common.paths: the configuration folder is found in a checkout, a devel space and an install space."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from helpers.paths import CONFIG, REPO

from uav_common.errors import ConfigError
from uav_common.paths import config_dir, config_file, repo_root, runs_dir


def fake_config(folder: Path) -> Path:
    """A copy of the marker and one scenario: what the lookup recognises as the configuration folder."""
    (folder / "scenarios").mkdir(parents=True)
    shutil.copy(CONFIG / "README.md", folder / "README.md")
    shutil.copy(CONFIG / "scenarios" / "loiter.yaml", folder / "scenarios" / "loiter.yaml")
    return folder


def test_the_checkout_is_found_from_any_file_inside_it() -> None:
    assert repo_root(REPO / "catkin_ws" / "src" / "uav_scenarios" / "setup.py") == REPO
    assert config_dir({}, REPO / "uav_common" / "src" / "uav_common" / "paths.py") == CONFIG
    assert config_file("scenarios", "loiter.yaml", environ={}) == CONFIG / "scenarios" / "loiter.yaml"


def test_an_install_space_wins_over_the_checkout(tmp_path: Path) -> None:
    """``source install/setup.bash`` puts the install prefix on CMAKE_PREFIX_PATH: its config is used."""
    installed = fake_config(tmp_path / "install" / "share" / "uav_config" / "config")
    env = {"CMAKE_PREFIX_PATH": f"{tmp_path / 'other'}:{tmp_path / 'install'}:/usr"}
    assert config_dir(env) == installed.resolve()


def test_a_devel_space_finds_the_package_through_ros_package_path(tmp_path: Path) -> None:
    src = tmp_path / "ws" / "src"
    fake_config(tmp_path / "real_config")
    (src / "uav_config").mkdir(parents=True)
    (src / "uav_config" / "config").symlink_to(tmp_path / "real_config")
    env = {"ROS_PACKAGE_PATH": str(src), "CMAKE_PREFIX_PATH": str(tmp_path / "ws" / "devel")}
    assert config_dir(env, start=tmp_path / "elsewhere.py") == (tmp_path / "real_config").resolve()


def test_uav_config_dir_overrides_and_must_be_a_configuration_folder(tmp_path: Path) -> None:
    mine = fake_config(tmp_path / "mine")
    assert config_dir({"UAV_CONFIG_DIR": str(mine)}) == mine.resolve()
    with pytest.raises(ConfigError, match=r"UAV_CONFIG_DIR=.* is not the project's configuration folder"):
        config_dir({"UAV_CONFIG_DIR": str(tmp_path)})


def test_nothing_found_says_where_it_looked_and_what_to_do(tmp_path: Path) -> None:
    env = {"CMAKE_PREFIX_PATH": str(tmp_path / "prefix"), "ROS_PACKAGE_PATH": str(tmp_path / "src")}
    with pytest.raises(ConfigError) as err:
        config_dir(env, start=tmp_path / "x.py")
    text = str(err.value)
    assert str(tmp_path / "prefix" / "share" / "uav_config" / "config") in text
    assert "UAV_CONFIG_DIR" in text
    with pytest.raises(ConfigError, match="no such configuration file"):
        config_file("nope.yaml", environ={})


def test_runs_go_where_the_environment_says_else_into_the_checkout(tmp_path: Path) -> None:
    assert runs_dir({"UAV_RUNS_DIR": str(tmp_path)}) == tmp_path
    assert runs_dir({}) == REPO / "runs"
    assert runs_dir({"HOME": str(tmp_path)}, start=tmp_path / "x.py") == tmp_path / ".ros" / "uav_runs"
