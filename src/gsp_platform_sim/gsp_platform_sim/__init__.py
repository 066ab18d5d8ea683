"""gsp_platform_sim: the simulated platform node (see docs/nodes.md)."""
