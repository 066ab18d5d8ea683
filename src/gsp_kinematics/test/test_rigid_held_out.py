"""The rigid geometry's held-out figure (gsp_kinematics.estimation.verdict.rigid_held_out): the mean length
of a fixed error plus a random one, against a Monte Carlo mean."""

import numpy as np

from gsp_kinematics.estimation.verdict.rigid_held_out import mean_sum_length


def test_the_mean_length_of_a_fixed_plus_a_random_error_matches_sampling():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(200_000, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    for fixed, random in ((10.0, 3.0), (3.0, 10.0), (5.0, 5.0), (0.0, 4.0)):
        sampled = np.mean(np.linalg.norm([fixed, 0.0, 0.0] + random * directions, axis=1))
        computed = float(mean_sum_length([fixed], random)[0])
        # 0.4 % (four standard errors of the sampled mean): the quadrature sum is 6 % off at
        # equal sizes.
        assert abs(computed - sampled) < 4e-3 * sampled, (fixed, random, computed, sampled)
