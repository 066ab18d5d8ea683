"""gsp_msgs_py: names, QoS profiles, conversions and the node skeleton of gsp-calibration.

A pure-Python layer over standard common_interfaces messages (like ``sensor_msgs_py``):
``names`` (topics, frames, joints), ``qos`` (profiles), ``conversions`` (messages <-> numpy
arrays), ``message_checks`` (incoming poses), ``node_tools`` (parameter specs, declare/watch, main),
``settle`` and ``pose_commands`` (the platform side of the command/status protocol),
``health`` and ``diagnostics`` (every node's health on ``/diagnostics``). The tests' helpers are
not shipped: they live in ``test_support/gsp_testing.py``. Submodules are imported on demand; importing this package is cheap.
"""

__version__ = '0.1.0'
