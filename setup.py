# All metadata is declarative, in setup.cfg (colcon reads it there without running code).
from setuptools import setup

setup()
