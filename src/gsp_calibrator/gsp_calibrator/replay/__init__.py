"""Replaying a recorded run: the recorded run (pure) and the `replay` node."""
