# catkin_python_setup() entry: installs the ROS-free Python package `quad_il` into the devel space.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["quad_il"], package_dir={"": "src"}))
