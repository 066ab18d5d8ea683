"""The package's own face: the names ``gsp_kinematics`` lends from its modules."""

import gsp_kinematics


def test_every_name_the_package_lends_resolves():
    """``from gsp_kinematics import X`` for every X in ``__all__`` (a module moved into a
    subpackage once left its names pointing at nothing)."""
    for name in gsp_kinematics.__all__:
        assert getattr(gsp_kinematics, name) is not None, name
