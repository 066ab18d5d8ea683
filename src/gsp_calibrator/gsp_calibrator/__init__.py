"""gsp_calibrator (see docs/design.md)."""
