"""The calibrator node's glue: its wiring, threads, sensor intake and result delivery (rclpy)."""
