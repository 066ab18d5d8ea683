"""gsp_device_driver: the device driver node and its backends (see docs/nodes.md)."""
