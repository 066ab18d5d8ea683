"""`recording.mcap`: the live recorder, the MCAP format and I/O, and the offline rebuild of a run from a recording."""
