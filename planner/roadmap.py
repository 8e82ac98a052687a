"""Per-arm roadmaps in configuration space and their candidate paths (thesis 6.3.4.1, 6.3.4.3).

A roadmap is built in three steps (thesis 6.3.4.1, fig. 6.8):

1. grid vertices (default 8 x 6 over theta1 x theta2, cell centres) outside the ZoA;
2. random extra edges between vertex pairs (each vertex in at most one pair), kept when the
   straight segment avoids the ZoA, in either theta2 direction;
3. paths start -> end, start -> v -> end and start -> vi -> vj -> end whose edges all
   avoid the ZoA.

theta2 is unbounded mechanically (J2 has no limit switches, thesis 3.5), so every edge may
turn theta2 either way round; coordinates along a path are *unwrapped*: each vertex's
theta2 is the previous one plus the signed turn, so a trajectory is linear and continuous
between way-points. Paths are ranked by the estimated travel time (thesis eq. 6.23),
most promising first; ties are broken by a seeded random key (the thesis picks
arbitrarily among equals).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.geometry import ArmGeom, edges_in_zoa

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class RoadmapPath:
    """One candidate path: way-points (n_edges + 1, 2), theta2 unwrapped; ``est_time_s`` is eq. 6.23."""

    waypoints: np.ndarray
    est_time_s: float
    rank_s: float = 0.0  # est_time_s plus the turn-sense bias: the exploration order key

    @property
    def n_edges(self) -> int:
        return len(self.waypoints) - 1


@dataclass(frozen=True)
class RoadmapParams:
    grid: tuple[int, int] = (8, 6)  # vertices along (theta1, theta2)
    max_edges_per_path: int = 3
    # task-specific vertices (beyond the thesis grid): the two "one joint at a time" corners
    # and a small ring around start and goal, where an arm can step aside and wait
    local_steps_rad: tuple[float, ...] = (0.3, 0.6)
    # paths whose net theta2 turn is against ``turn_sense`` rank ``turn_bias_s`` later: neighbours
    # turning J2 the same way sweep alongside each other instead of into each other
    turn_sense: int = 1
    turn_bias_s: float = 0.0


def grid_vertices(geom: ArmGeom, grid: tuple[int, int]) -> np.ndarray:
    """(n, 2) grid vertices (cell centres) outside the ZoA (thesis fig. 6.8a); theta2 in [0, 2 pi)."""
    n1, n2 = grid
    t1 = geom.theta1_min + (np.arange(n1) + 0.5) * (geom.theta1_max - geom.theta1_min) / n1
    t2 = (np.arange(n2) + 0.5) * TWO_PI / n2
    g1, g2 = np.meshgrid(t1, t2, indexing="ij")
    v = np.column_stack([g1.ravel(), g2.ravel()])
    return v[~geom.in_zoa(v[:, 0], v[:, 1])]


def local_vertices(geom: ArmGeom, q_start: np.ndarray, q_goal: np.ndarray,
                   steps_rad: tuple[float, ...]) -> np.ndarray:
    """Corners (theta1_s, theta2_g), (theta1_g, theta2_s) and rings around start and goal, outside the ZoA."""
    pts = [[q_start[0], q_goal[1]], [q_goal[0], q_start[1]]]
    for c in (q_start, q_goal):
        for r in steps_rad:
            for a in np.arange(8) * np.pi / 4:
                pts.append([c[0] + r * np.cos(a), c[1] + r * np.sin(a)])
    v = np.asarray(pts, float)
    v[:, 1] = np.mod(v[:, 1], TWO_PI)
    return v[~geom.in_zoa(v[:, 0], v[:, 1])]


def _turns(theta2_from: np.ndarray, theta2_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed theta2 turns (ccw >= 0, cw <= 0) taking theta2_from to theta2_to modulo 2 pi."""
    ccw = np.mod(np.asarray(theta2_to) - np.asarray(theta2_from), TWO_PI)
    return ccw, np.where(ccw > 0, ccw - TWO_PI, 0.0)


def candidate_paths(geom: ArmGeom, q_start: np.ndarray, q_goal: np.ndarray, rng: np.random.Generator,
                    params: RoadmapParams = RoadmapParams()) -> list[RoadmapPath]:
    """Every ZoA-free roadmap path start -> goal, most promising first (thesis 6.3.4.1-6.3.4.3).

    ``q_start`` carries the unwrapped theta2 the arm really has; the goal's theta2 counts
    modulo 2 pi (the path ends at the unwrapped value reached by the chosen turns).
    """
    qs = np.asarray(q_start, float)
    qg = np.asarray(q_goal, float)
    V = np.concatenate([grid_vertices(geom, params.grid), local_vertices(geom, qs, qg, params.local_steps_rad)])
    paths: list[tuple[np.ndarray, float]] = []

    def edge_time(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return geom.move_time_s(a, b)

    # direct: both theta2 directions (thesis: "a direct path ... if it is feasible")
    ccw, cw = _turns(qs[1], qg[1])
    turns = np.unique(np.array([ccw, cw]))
    ends = np.column_stack([np.full(len(turns), qg[0]), qs[1] + turns])
    ok = ~edges_in_zoa(geom, np.broadcast_to(qs, ends.shape), ends)
    for e in ends[ok]:
        wp = np.array([qs, e])
        paths.append((wp, float(edge_time(qs, e))))

    if params.max_edges_per_path >= 2 and len(V):
        # start -> v (two turns each), v -> goal (two turns each)
        c1, w1 = _turns(qs[1], V[:, 1])
        sv = np.concatenate([np.column_stack([V[:, 0], qs[1] + c1]), np.column_stack([V[:, 0], qs[1] + w1])])
        sv_ok = ~edges_in_zoa(geom, np.broadcast_to(qs, sv.shape), sv)
        c2, w2 = _turns(V[:, 1], qg[1])
        # v -> goal depends only on the turn, not on v's unwrapping: check with v in [0, 2 pi)
        vg_c = np.column_stack([np.full(len(V), qg[0]), V[:, 1] + c2])
        vg_w = np.column_stack([np.full(len(V), qg[0]), V[:, 1] + w2])
        vg_ok_c = ~edges_in_zoa(geom, V, vg_c)
        vg_ok_w = ~edges_in_zoa(geom, V, vg_w)
        nv = len(V)
        for j in range(2 * nv):
            if not sv_ok[j]:
                continue
            i = j % nv
            v = sv[j]
            t_sv = float(edge_time(qs, v))
            for turn, okk in ((c2[i], vg_ok_c[i]), (w2[i], vg_ok_w[i])):
                if okk:
                    g = np.array([qg[0], v[1] + turn])
                    paths.append((np.array([qs, v, g]), t_sv + float(edge_time(v, g))))

        if params.max_edges_per_path >= 3 and nv >= 2:
            # random vertex pairs, each vertex in at most one pair (thesis 6.3.4.1 step 2)
            perm = rng.permutation(nv)
            pa, pb = perm[0:nv - 1:2], perm[1:nv:2]
            pa, pb = np.concatenate([pa, pb]), np.concatenate([pb, pa])  # both orientations
            cc, ww = _turns(V[pa, 1], V[pb, 1])
            for turn in (cc, ww):
                bq = np.column_stack([V[pb, 0], V[pa, 1] + turn])
                ok_ab = ~edges_in_zoa(geom, V[pa], bq)
                for a_i, b_i, tb, okk in zip(pa, pb, turn, ok_ab, strict=True):
                    if not okk:
                        continue
                    for ja in (a_i, a_i + nv):
                        if not sv_ok[ja]:
                            continue
                        va = sv[ja]
                        vb = np.array([V[b_i, 0], va[1] + tb])
                        for turn_g, okg in ((c2[b_i], vg_ok_c[b_i]), (w2[b_i], vg_ok_w[b_i])):
                            if okg:
                                g = np.array([qg[0], vb[1] + turn_g])
                                wp = np.array([qs, va, vb, g])
                                t = float(edge_time(qs, va) + edge_time(va, vb) + edge_time(vb, g))
                                paths.append((wp, t))

    # most promising first (eq. 6.23); then fewer edges; seeded tie-break
    key = rng.random(len(paths))
    rank = [t + (params.turn_bias_s if (wp[-1, 1] - wp[0, 1]) * params.turn_sense < -1e-9 else 0.0)
            for wp, t in paths]
    order = sorted(range(len(paths)), key=lambda k: (round(rank[k], 6), len(paths[k][0]), key[k]))
    return [RoadmapPath(paths[k][0], paths[k][1], rank[k]) for k in order]
