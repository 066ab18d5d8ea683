"""gsp_platform_bridge: the package metadata is in setup.cfg (ament_python needs this file)."""

from setuptools import setup

setup()
