"""The platform as physics (floor 1 of the core, above channels, rotation and fileio): its
kinematics, geometry and device, the effects' formulas, the sensors' noise and dynamics, and
the legs' motion. Imports nothing of estimation/, planning/ or upkeep/."""
