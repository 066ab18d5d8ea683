"""gsp_calibrator: the calibrator node, its collection protocol, run data, replay, upkeep and user tools (see docs/architecture.md)."""
