"""Physical effects of a real hexapod that the 44-parameter model leaves out (docs/platform_effects.md):
leg compliance under the platform's weight, backlash, thermal growth of the legs and base U
joints whose two axes do not intersect. :mod:`.model` holds the parameters and each effect's
physics; :mod:`.real_pose` the pose a platform with them takes for given leg readings.
"""
