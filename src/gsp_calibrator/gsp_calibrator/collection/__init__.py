"""Collecting postures: the pure collection protocol, its stamp synchroniser and the one-source-per-topic check (no rclpy)."""
