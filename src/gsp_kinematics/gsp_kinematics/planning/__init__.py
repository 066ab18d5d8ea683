"""What to measure (floor 3 of the core, above estimation/): the postures to select, the route
through them and the plans that identify the effects."""
