"""Keeping a platform calibrated (docs/upkeep.md): the check's run and the history's plot."""
