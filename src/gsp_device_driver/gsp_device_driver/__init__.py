"""gsp_device_driver (see docs/design.md)."""
