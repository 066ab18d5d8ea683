"""Keeping a platform calibrated (docs/upkeep.md): reading calibrations and checks back from their
run directories, the platform's history (SQLite) and the check's run. Pure except the check's
node side."""
