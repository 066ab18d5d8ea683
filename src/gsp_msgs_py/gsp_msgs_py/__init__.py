"""gsp_msgs_py: names, QoS profiles, conversions and the node skeleton of gsp-calibration.

A pure-Python layer over standard common_interfaces messages (like ``sensor_msgs_py``):
``names`` (topics, frames, joints), ``qos`` (profiles), ``conversions`` (messages <-> numpy
arrays), ``message_checks`` (incoming messages), ``parameter_specs`` (the parameter tables),
``node_tools`` (declare/watch, ``main``), ``geometry_parameters`` (the ``geometry.*`` set),
``settle`` and ``pose_commands`` (the platform side of the command/status protocol), ``health``
and ``diagnostics`` (every node's health on ``/diagnostics``), ``ros_environment`` (the network
rule), ``executors`` and ``interfaces`` (the driver contract). The tests' helpers live in
``test_support/gsp_testing.py``. Submodules are imported on demand.
"""

__version__ = '0.1.0'
