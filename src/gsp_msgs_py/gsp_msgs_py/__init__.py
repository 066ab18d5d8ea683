"""gsp_msgs_py: names, QoS profiles, conversions and the node skeleton of gsp-calibration."""

__version__ = '0.1.0'
