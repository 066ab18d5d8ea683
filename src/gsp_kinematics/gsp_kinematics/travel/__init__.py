"""The platform's travel between postures: leg speed and acceleration limits and the time of a
move (:mod:`.motion`), and the shortest route through a set of postures (:mod:`.route`). Pure
numpy and scipy."""
