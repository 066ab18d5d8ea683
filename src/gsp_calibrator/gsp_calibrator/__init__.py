"""gsp_calibrator: the calibrator node, its collection protocol, run data, replay, demo and benchmark (see docs/architecture.md)."""
