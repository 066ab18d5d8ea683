"""gsp_msgs_py: names, QoS profiles, units and conversions for gsp-calibration interfaces.

A pure-Python layer over standard common_interfaces messages (like ``sensor_msgs_py``):
``names`` (topics, frames, joints), ``qos`` (profiles), ``units``, ``conversions``
(messages <-> numpy arrays). Submodules are imported on demand; importing this package is cheap.
"""

__version__ = '0.1.0'
