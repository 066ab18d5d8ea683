"""Keeping a platform calibrated: the short check (check), the change between two
calibrations (drift), and a run that stops when it is good enough (stopping)."""
