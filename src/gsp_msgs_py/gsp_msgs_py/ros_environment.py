"""The network rule in one place: DDS on loopback, in a private ROS domain (no rclpy needed).

Every test, demo and benchmark process runs with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and
its own ``ROS_DOMAIN_ID``, so discovery never reaches another interface or another run.
"""

import os
import random

#: Domain ids drawn by :func:`random_domain_id` (valid for any participant count on Linux).
DOMAIN_IDS = range(1, 102)


def random_domain_id(rng=None, exclude=()):
    """A domain id from :data:`DOMAIN_IDS`, avoiding ``exclude``; ``rng`` a ``random.Random``."""
    rng = rng or random.SystemRandom()
    choices = [d for d in DOMAIN_IDS if d not in set(exclude)] or list(DOMAIN_IDS)
    return rng.choice(choices)


def loopback_environment(environ=None, rng=None, exclude=()):
    """A copy of ``environ`` (default ``os.environ``) with discovery kept on loopback.

    An existing non-empty ``ROS_DOMAIN_ID`` is kept; otherwise one is drawn
    (:func:`random_domain_id`).
    """
    env = dict(os.environ if environ is None else environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if not env.get('ROS_DOMAIN_ID', '').strip():
        env['ROS_DOMAIN_ID'] = str(random_domain_id(rng, exclude))
    return env
