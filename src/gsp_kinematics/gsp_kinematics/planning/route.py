"""The order to visit a set of postures in: the shortest route in platform time (pure numpy/scipy)
(docs/planning.md)."""

import dataclasses

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

from ..model.motion import move_time, posture_leg_lengths

#: Improvements smaller than this (s) end the local search (rounding, not a better route).
TOLERANCE_S = 1e-9
#: Longest run of postures Or-opt moves.
OR_OPT_RUN = 3


def travel_time_matrix(legs, limits):
    """(N, N) synchronised move times (s) between leg-length vectors ``legs`` (N, 6) m."""
    legs = np.asarray(legs, dtype=float)
    return move_time(legs[:, None, :], legs[None, :, :], limits)


def path_time(times, path):
    """Travel time (s) of visiting ``path`` (node indices of ``times``) in order."""
    path = np.asarray(path)
    return float(times[path[:-1], path[1:]].sum())


def _nearest_neighbour(times, start):
    size = times.shape[0]
    visited = np.zeros(size, dtype=bool)
    visited[start] = True
    path = [start]
    for _ in range(size - 1):
        row = np.where(visited, np.inf, times[path[-1]])
        path.append(int(np.argmin(row)))
        visited[path[-1]] = True
    return path


def _best_two_opt(extended, path):
    """Best 2-opt move of ``path`` (ends fixed): ``(gain, i, j)`` reverses path[i..j]."""
    a, b = path[:-1], path[1:]  # edge k joins a[k] and b[k]
    joined = extended[a[:, None], a[None, :]] + extended[b[:, None], b[None, :]]
    removed = extended[a, b]
    gain = removed[:, None] + removed[None, :] - joined
    gain = np.triu(gain, k=1)  # edge e2 after edge e1
    e1, e2 = np.unravel_index(int(np.argmax(gain)), gain.shape)
    return float(gain[e1, e2]), int(e1) + 1, int(e2)


def _best_or_opt(extended, path):
    """Best Or-opt move: ``(gain, new path)`` (None if no gain)."""
    last = len(path) - 1  # the dummy end stays last, the start first
    a, b = path[:-1], path[1:]
    edge = extended[a, b]
    best_gain, best_path = TOLERANCE_S, None
    for run in range(1, OR_OPT_RUN + 1):
        for i in range(1, last - run + 1):
            first, final = path[i], path[i + run - 1]
            before, after = path[i - 1], path[i + run]
            removal = edge[i - 1] + edge[i + run - 1] - extended[before, after]
            # Edges k that survive the removal: not i-1 .. i+run-1.
            k = np.r_[0 : i - 1, i + run : last]
            forward = extended[a[k], first] + extended[final, b[k]] - edge[k]
            backward = extended[a[k], final] + extended[first, b[k]] - edge[k]
            costs = np.minimum(forward, backward)
            if not costs.size:
                continue
            where = int(np.argmin(costs))
            gain = removal - costs[where]
            if gain > best_gain:
                segment = path[i : i + run]
                if backward[where] < forward[where]:
                    segment = segment[::-1]
                rest = np.r_[path[:i], path[i + run :]]
                edge_k = int(k[where])
                position = edge_k + 1 if edge_k < i else edge_k + 1 - run
                best_gain = gain
                best_path = np.r_[rest[:position], segment, rest[position:]]
    return best_gain, best_path


def shortest_path_order(times, start=0, max_passes=10_000):
    """Node order (a permutation of ``range(N)`` beginning with ``start``) of a short open path
    over the symmetric travel times ``times`` (N, N) s: nearest neighbour, then 2-opt and Or-opt."""
    times = np.asarray(times, dtype=float)
    size = times.shape[0]
    if times.shape != (size, size) or not 0 <= start < size:
        raise ValueError(f'times must be square (N, N) with 0 <= start < N, got {times.shape}')
    if size <= 2:
        return np.array([start, *[n for n in range(size) if n != start]])
    # A dummy end node, 0 s from every node, makes the path's free end a fixed last node.
    extended = np.zeros((size + 1, size + 1))
    extended[:size, :size] = times
    path = np.array([*_nearest_neighbour(times, start), size])
    for _ in range(max_passes):
        gain, i, j = _best_two_opt(extended, path)
        if gain > TOLERANCE_S:
            path[i : j + 1] = path[i : j + 1][::-1]
            continue
        gain, moved = _best_or_opt(extended, path)
        if moved is None:
            break
        path = moved
    return path[:-1]


def spanning_tree_bound(times):
    """Weight (s) of the minimum spanning tree of ``times`` (N, N): no path through every node
    is shorter."""
    times = np.array(times, dtype=float)
    # The graph routine reads 0 as "no edge": coincident postures get a negligible weight.
    off_diagonal = ~np.eye(times.shape[0], dtype=bool)
    times[off_diagonal & (times <= 0.0)] = 1e-15
    np.fill_diagonal(times, 0.0)
    return float(minimum_spanning_tree(times).sum())


@dataclasses.dataclass(frozen=True)
class Route:
    """The order to command a set of postures in, and its travel times (s)."""

    order: np.ndarray  #: (N,) posture indices in visiting order
    travel_s: float  #: travel time of the route from the start posture
    selection_order_s: float  #: travel time of the postures in their given order
    lower_bound_s: float  #: minimum spanning tree of the start and the postures


def plan_route(geometry, start_pose, poses, limits):
    """The route through ``poses`` (N, 6) from ``start_pose`` (6,), commanded by a controller
    with ``geometry`` whose legs move within ``limits`` (:class:`gsp_kinematics.model.motion.MotionLimits`)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    legs = posture_leg_lengths(geometry, np.vstack([np.asarray(start_pose, float)[None], poses]))
    times = travel_time_matrix(legs, limits)
    path = shortest_path_order(times, 0)
    return Route(
        order=path[1:] - 1,
        travel_s=path_time(times, path),
        selection_order_s=path_time(times, np.arange(len(legs))),
        lower_bound_s=spanning_tree_bound(times),
    )
