# The ecar_sim Python package (src/ecar_sim/python/ecar_sim): run_session (ecar_sim.session),
# its VO and plane metrics, the alignment the Python tools share, and the paper's experiments
# (ecar_sim.reproduce, scripts/reproduce.sh).
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["ecar_sim", "ecar_sim.session", "ecar_sim.reproduce"],
                                 package_dir={"": "python"}))
