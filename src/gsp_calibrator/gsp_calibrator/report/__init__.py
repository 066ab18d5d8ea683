"""The report of a calibration: `result.json`, `report.md` and its plots (pure, no rclpy)."""
