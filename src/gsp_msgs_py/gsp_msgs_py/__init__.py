"""gsp_msgs_py: names, QoS profiles, conversions and the node skeleton of gsp-calibration.

A pure-Python layer over standard common_interfaces messages: ``names`` (topics, frames, joints),
``qos`` (profiles), ``conversions`` (messages <-> numpy), ``message_checks`` (incoming messages),
``parameter_specs`` (the parameter tables), ``node_tools`` (declare, watch, run a node),
``geometry_parameters`` (the ``geometry.*`` set), ``settle`` and ``pose_commands`` (the platform
side of the command protocol), ``health`` and ``diagnostics`` (health on ``/diagnostics``),
``ros_environment`` (the network rule), ``executors`` and ``interfaces`` (the driver contract).
"""

__version__ = '0.1.0'
