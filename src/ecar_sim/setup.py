# The ecar_sim Python package (src/ecar_sim/python/ecar_sim): run_session (ecar_sim.session),
# its VO and plane metrics, and the alignment the Python tools share.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["ecar_sim", "ecar_sim.session"],
                                 package_dir={"": "python"}))
