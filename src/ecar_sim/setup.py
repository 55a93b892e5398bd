# The ecar_sim Python package (src/ecar_sim/python/ecar_sim): session metrics for run_session.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["ecar_sim"], package_dir={"": "python"}))
