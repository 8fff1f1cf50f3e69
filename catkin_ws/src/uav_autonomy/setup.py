"""catkin_python_setup() entry: the importable package lives in src/uav_autonomy (REP 8)."""

from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(
    **generate_distutils_setup(
        packages=["uav_autonomy", "uav_autonomy.core", "uav_autonomy.ros", "uav_autonomy.nodes"],
        package_dir={"": "src"},
    )
)
