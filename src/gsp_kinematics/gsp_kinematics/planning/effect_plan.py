"""Plans that can identify the effects (docs/platform_effects.md#plans-that-identify-the-effects)."""

import dataclasses

import numpy as np

from ..estimation.identifiability import DEFAULT_RELATIVE_TOLERANCE, posture_information
from ..estimation.identification import resolve_free
from ..model.effect_groups import EffectDesign, EffectTerms, resolve_effects
from ..model.effects import EFFECT_GROUPS, EFFECT_PARAMETER_NAMES, NUM_LEGS, approach_directions
from ..model.geometry import ALL_PARAMETER_NAMES
from ..model.motion import MotionLimits, move_time, posture_leg_lengths
from ..model.sensor_noise import DEFAULT_SENSOR_NOISE

#: Postures between reference revisits when thermal is planned and no interval is given; 0:
#: none, the reference is revisited at the end only (the plan's other postures, at their own
#: times, hold most of the drift's information).
DEFAULT_REVISIT_EVERY = 0
#: Most postures :func:`augment_route` inserts for the approach directions.
MAX_APPROACH_INSERTIONS = 24
#: An instantaneous platform: no travel time (the times are then ``dwell_s`` per posture).
INSTANTANEOUS = MotionLimits(np.inf, np.inf)


@dataclasses.dataclass(frozen=True)
class AugmentedRoute:
    """The route to command, with what it adds for the effect groups (times in s)."""

    poses: np.ndarray  #: (N, 6) in the order to command
    source: np.ndarray  #: (N,) index of each into the plan's poses (-1: the reference pose)
    kind: tuple  #: (N,) 'plan', 'reference' (a revisit) or 'approach' (a posture measured again)
    times_s: np.ndarray  #: (N,) predicted time of each measurement since the start
    directions: np.ndarray  #: (N, 6) each leg's approach direction (+1 extending)
    arrivals: np.ndarray  #: (6, 2) per leg: arrivals extending, retracting
    one_way_legs: tuple  #: legs (1-6) with fewer than ``min_arrivals`` arrivals one way
    plain_s: float  #: platform time of the plain route (travel and dwell)
    total_s: float  #: platform time of this route

    @property
    def added_s(self):
        """Platform time (s) the additions cost over the plain route."""
        return self.total_s - self.plain_s

    @property
    def added_postures(self):
        return int(sum(kind != 'plan' for kind in self.kind))

    def design(
        self,
        payload_mass=0.0,
        centre_of_mass=(0.0, 0.0, 0.0),
        reference_time_s=None,
        thermal_time_constant_s=0.0,
    ):
        """The :class:`EffectDesign` of measuring this route at its predicted times
        (``reference_time_s`` default: the last measurement)."""
        reference = self.times_s[-1] if reference_time_s is None else reference_time_s
        return EffectDesign(
            self.times_s,
            self.directions,
            payload_mass,
            tuple(centre_of_mass),
            float(reference),
            float(thermal_time_constant_s),
        )

    def to_dict(self):
        """JSON-ready summary (without the poses)."""
        return {
            'postures': len(self.poses),
            'added_postures': self.added_postures,
            'reference_revisits': int(sum(kind == 'reference' for kind in self.kind)),
            'approach_insertions': int(sum(kind == 'approach' for kind in self.kind)),
            'plain_s': self.plain_s,
            'total_s': self.total_s,
            'added_s': self.added_s,
            'arrivals_extending': self.arrivals[:, 0].tolist(),
            'arrivals_retracting': self.arrivals[:, 1].tolist(),
            'one_way_legs': list(self.one_way_legs),
            'order': self.source.tolist(),
            'kind': list(self.kind),
        }


def _timeline(legs, sequence, start_legs, dwell_s, limits):
    """Measurement times (N,) and the total platform time of visiting ``sequence`` (node
    indices into ``legs``) from ``start_legs``: each move, then ``dwell_s`` at the posture."""
    path = np.vstack([start_legs[None], legs[sequence]])
    moves = move_time(path[:-1], path[1:], limits)
    ends = np.cumsum(moves + dwell_s)
    return ends - dwell_s, float(ends[-1]) if len(ends) else 0.0


def _with_revisits(count, reference, every, interval_s, node_times):
    """The sequence with the reference node revisited: at the start, whenever ``every`` postures
    or ``interval_s`` of (plain-route) time have passed since the last visit, and at the end."""
    sequence = [reference] if reference >= count else []
    since, last_time = 0, 0.0
    for k in range(count):
        due = (every and since >= every) or (interval_s and node_times[k] - last_time >= interval_s)
        if due and sequence and sequence[-1] != reference:
            sequence.append(reference)
            since, last_time = 0, node_times[k]
        sequence.append(k)
        since = 0 if k == reference else since + 1
        last_time = node_times[k] if k == reference else last_time
    if sequence[-1] != reference:
        sequence.append(reference)
    return sequence


def _arrivals(legs, sequence, start_legs):
    directions = approach_directions(legs[sequence], start_legs)
    counts = np.stack([(directions > 0).sum(axis=0), (directions < 0).sum(axis=0)], axis=1)
    return directions, counts


def _cheapest_approach(legs, sequence, start_legs, leg, side, times):
    """``(position, node)``: the cheapest insertion of a plan node just before ``position`` of
    ``sequence`` from which ``leg`` arrives there moving ``side`` (+1 extending); None."""
    plan_nodes = np.arange(len(legs) - 1)  # the last node is the start
    best, best_cost = None, np.inf
    previous = [len(legs) - 1] + list(sequence[:-1])
    for position, (before, node) in enumerate(zip(previous, sequence, strict=True)):
        moves = np.sign(legs[node, leg] - legs[plan_nodes, leg])
        usable = plan_nodes[(moves == side) & (plan_nodes != node) & (plan_nodes != before)]
        if not len(usable):
            continue
        cost = times[before, usable] + times[usable, node] - times[before, node]
        pick = int(np.argmin(cost))
        if cost[pick] < best_cost:
            best, best_cost = (position, int(usable[pick])), cost[pick]
    return best


def augment_route(
    geometry,
    poses,
    groups,
    start_pose=None,
    reference_pose=None,
    revisit_every=None,
    revisit_interval_s=None,
    dwell_s=0.0,
    limits=INSTANTANEOUS,
    min_arrivals=1,
):
    """The :class:`AugmentedRoute` of commanding ``poses`` (N, 6, in route order) for the effect
    ``groups`` a calibration will free, by a controller with ``geometry``: ``thermal``, revisits
    of ``reference_pose`` (default the first) every ``revisit_every`` postures and/or
    ``revisit_interval_s`` s and at the end; ``backlash``, ``min_arrivals`` arrivals of each leg
    both ways. Moves within ``limits``, ``dwell_s`` per posture, from ``start_pose``
    (docs/platform_effects.md)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    count = len(poses)
    groups = [groups] if isinstance(groups, str) else list(groups)
    unknown = set(groups) - set(EFFECT_GROUPS)
    if unknown:
        raise ValueError(
            f'unknown effect groups {sorted(unknown)}; expected some of {list(EFFECT_GROUPS)}'
        )
    start = poses[0] if start_pose is None else np.asarray(start_pose, dtype=float)
    extra = [] if reference_pose is None else [np.asarray(reference_pose, dtype=float)]
    # Nodes: the plan's poses, the reference (if given apart), then the start (last).
    nodes = np.vstack([poses, *[p[None] for p in extra], start[None]])
    legs = posture_leg_lengths(geometry, nodes)
    start_legs = legs[-1]
    plain_times, plain_s = _timeline(legs, np.arange(count), start_legs, dwell_s, limits)
    sequence = list(range(count))
    reference = count if extra else 0
    if 'thermal' in groups:
        every = revisit_every
        if every is None and revisit_interval_s is None:
            every = DEFAULT_REVISIT_EVERY
        sequence = _with_revisits(count, reference, every, revisit_interval_s, plain_times)
    kinds = ['plan' if k < count else 'reference' for k in sequence]
    if 'thermal' in groups:  # the visits of the reference after its first are revisits
        first = sequence.index(reference)
        kinds = [
            'reference' if (k == reference and i > first) else kind
            for i, (k, kind) in enumerate(zip(sequence, kinds, strict=True))
        ]
    if 'backlash' in groups:
        sequence, kinds = _both_directions(legs, sequence, kinds, start_legs, limits, min_arrivals)
    directions, arrivals = _arrivals(legs, sequence, start_legs)
    times, total_s = _timeline(legs, np.asarray(sequence), start_legs, dwell_s, limits)
    one_way = tuple(int(leg) + 1 for leg in np.flatnonzero(arrivals.min(axis=1) < min_arrivals))
    source = np.array([k if k < count else -1 for k in sequence])
    return AugmentedRoute(
        nodes[sequence],
        source,
        tuple(kinds),
        times,
        directions,
        arrivals,
        one_way,
        plain_s,
        total_s,
    )


def _both_directions(legs, sequence, kinds, start_legs, limits, min_arrivals):
    """Insert plan postures until each leg arrives ``min_arrivals`` times each way (or no
    insertion helps, or :data:`MAX_APPROACH_INSERTIONS`)."""
    times = move_time(legs[:, None], legs[None], limits)
    sequence, kinds = list(sequence), list(kinds)
    for _ in range(MAX_APPROACH_INSERTIONS):
        _, counts = _arrivals(legs, sequence, start_legs)
        short = np.argwhere(counts < min_arrivals)
        if not len(short):
            break
        leg, column = short[0]
        found = _cheapest_approach(legs, sequence, start_legs, leg, 1 - 2 * column, times)
        if found is None:
            break
        position, node = found
        sequence.insert(position, node)
        kinds.insert(position, 'approach')
    return sequence, kinds


def effect_information(geometry, poses, design, groups, sigmas=DEFAULT_SENSOR_NOISE, free=None):
    """Information matrix of the free geometric parameters (``free``, default the 44) then the
    effect parameters of ``groups`` (6 each) for measuring ``poses`` (M, 6) with the
    :class:`EffectDesign` ``design`` (rows of ``poses``) at the row ``sigmas`` (implicit
    formulation, the poses eliminated); and the names of its columns."""
    poses = np.atleast_2d(poses)
    mask = resolve_effects(groups)
    free_mask = resolve_free(free)
    columns = EffectTerms(geometry, design, mask, len(poses)).regressors(poses)
    information = posture_information(
        geometry, poses, sigmas, free_mask, 'implicit', leg_columns=columns
    ).sum(axis=0)
    names = [n for n, f in zip(ALL_PARAMETER_NAMES, free_mask, strict=True) if f]
    names += [n for n, f in zip(EFFECT_PARAMETER_NAMES, mask, strict=True) if f]
    return information, names, columns


def _scaled_rank(information, relative_tolerance=DEFAULT_RELATIVE_TOLERANCE):
    scale = 1.0 / np.sqrt(np.maximum(np.diag(information), 1e-300))
    singular = np.sqrt(np.maximum(np.linalg.eigvalsh(information * np.outer(scale, scale)), 0.0))
    return int(np.sum(singular > relative_tolerance * singular[-1]))


def group_identifiability(geometry, poses, design, group, sigmas=DEFAULT_SENSOR_NOISE, free=None):
    """One group freed beside the geometry: ``{rank, parameters, rank_plain, identifiable,
    crb_std, crb_leg_um, worst_correlations}``: Cramér-Rao stds (the parameters' units), the leg
    length each resolves (um) and per parameter its most correlated geometric parameter."""
    information, names, columns = effect_information(geometry, poses, design, [group], sigmas, free)
    geometric = len(names) - NUM_LEGS
    rank, rank_plain = _scaled_rank(information), _scaled_rank(information[:geometric, :geometric])
    entry = {
        'rank': rank,
        'parameters': len(names),
        'rank_plain': rank_plain,
        'identifiable': rank == len(names),
        'unit': EFFECT_GROUPS[group][1],
        'names': names[geometric:],
        'crb_std': None,
        'crb_leg_um': None,
        'worst_correlations': None,
    }
    if rank < len(names):
        return entry
    covariance = np.linalg.inv(information)
    deviations = np.sqrt(np.diag(covariance))
    correlations = covariance / np.outer(deviations, deviations)
    rms = np.sqrt(np.mean(np.sum(columns**2, axis=1), axis=0))  # each column is one leg's row
    entry['crb_std'] = deviations[geometric:].tolist()
    entry['crb_leg_um'] = (1e6 * deviations[geometric:] * rms).tolist()
    partners = np.argmax(np.abs(correlations[geometric:, :geometric]), axis=1)
    entry['worst_correlations'] = [
        {
            'parameter': names[row],
            'with': names[partner],
            'correlation': float(correlations[row, partner]),
        }
        for row, partner in enumerate(partners.tolist(), start=geometric)
    ]
    return entry


def effect_identifiability(geometry, poses, design, groups, sigmas=DEFAULT_SENSOR_NOISE, free=None):
    """``{group: group_identifiability(...)}`` for each of ``groups`` the ``design`` allows
    (a group it cannot describe, e.g. compliance without a mass, gets ``{'error': why}``)."""
    report = {}
    for group in groups:
        try:
            report[group] = group_identifiability(geometry, poses, design, group, sigmas, free)
        except ValueError as error:
            report[group] = {'error': str(error)}
    return report
