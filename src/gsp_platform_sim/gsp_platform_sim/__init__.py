"""gsp_platform_sim (see docs/design.md)."""
