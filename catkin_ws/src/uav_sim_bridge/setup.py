"""catkin_python_setup() entry: the importable package lives in src/uav_sim_bridge (REP 8)."""

from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(
    **generate_distutils_setup(
        packages=[
            "uav_sim_bridge",
            "uav_sim_bridge.core",
            "uav_sim_bridge.render",
            "uav_sim_bridge.ros",
            "uav_sim_bridge.nodes",
        ],
        package_dir={"": "src"},
    )
)
