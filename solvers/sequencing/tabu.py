"""Tabu search for packing targets into a fixed number of configurations.

The question the sequence repacking asks is a feasibility one: can these targets be
observed in ``n`` configurations, each obeying eqs. 5.13–5.15 (one location per arm, one
arm per target, no incompatible pair)?  CP-SAT answers it exactly but, on the thesis
protocol's weakly clustered fields, often neither finds nor refutes a packing into
⌈t/12⌉ configurations in its budget — with t = 96, 192, 384 that packing leaves no arm
idle, a perfect packing.  This module searches for one the way PartialCol searches for a
graph colouring (Blöchliger & Zufferey 2008, "A graph coloring heuristic using partial
solutions and a reactive tabu scheme"): a configuration is a colour, a target takes one
(configuration, arm location); the partial solution is always valid and the unplaced
targets are what the search minimises.

* **move**: an unplaced target takes a location in a configuration; the targets there that
  it conflicts with (same arm, or an incompatible pair) are ejected — the move's cost is
  how many;
* **tabu**: an ejected target may not go back to that configuration for
  ``0.6 |unplaced| + U(0, 9)`` iterations (PartialCol's tenure), unless the move would
  leave fewer targets unplaced than ever before (aspiration);
* **rests**: idle arms need a rest location (park, blank sky) compatible with their
  configuration; checked when nothing is unplaced, and a configuration whose idle arm has
  no compatible rest ejects the targets in the way and the search goes on.

The conflict counts per (location, configuration) are kept incrementally in a dense
matrix, so a move costs a few vectorised column updates.  It proves nothing: a ``None``
means "not found in time"; the callers keep CP-SAT for proofs and re-verify every
configuration geometrically.
"""

from __future__ import annotations

import numpy as np

from models import clock
from models.incompatibility import Incompatibility
from solvers.effort import TABU_CELL_S, TABU_MOVE_S
from solvers.model import conflict_adjacency

__all__ = ["tabu_pack"]

MAX_LOCATIONS = 12_000  # the dense conflict matrix is MAX_LOCATIONS² bytes at most


def tabu_pack(inc: Incompatibility, pool: np.ndarray, n_configs: int, *, time_limit_s: float,
              seed: int = 0, hint: list[np.ndarray] | None = None,
              max_iterations: int | None = None, stats: dict | None = None,
              weighting: bool = True, restart_after: int | None = -1,
              partial_out: list | None = None) -> list[np.ndarray] | None:
    """Place every target of ``pool`` in one of ``n_configs`` configurations.

    ``hint``: configurations to start from (per configuration the (n_arms,) assignment
    indices, e.g. the sequence being repacked); the ``n_configs`` holding most pooled
    targets are kept.  Returns per configuration the (n_arms,) chosen assignment indices
    (idle arms on a compatible rest location), or None when no packing was found within
    ``time_limit_s`` / ``max_iterations``.  After ``restart_after`` moves without a new
    fewest-unplaced the search restarts from a random greedy start (None: never; default
    max(5000, 50 per pooled target) — on the protocol's fields every packing found was
    found within ~3,500 moves of a start, and a start can be a bad one, hint included).  ``stats``
    (optional) receives the iterations, restarts and the fewest targets ever left unplaced.
    ``partial_out`` (optional list) receives, when the search ran and found no packing, the partial packing
    with the fewest unplaced targets: per configuration the assignment indices of its
    placed targets (a start for CP-SAT, :func:`solvers.packing_cpsat.max_cover`).
    """
    t0 = clock.now()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    pool = np.unique(np.asarray(pool, np.int64))
    if n_configs <= 0:
        return [] if not len(pool) else None
    if len(pool) > n_arms * n_configs:
        return None
    rng = np.random.default_rng(seed)
    if restart_after == -1:
        restart_after = max(5000, 50 * len(pool))
    n_all = len(a)
    rests = [np.flatnonzero(a.target[a.of_arm(k)] < 0) + int(a.arm_start[k]) for k in range(n_arms)]
    # an arm with one location and no pooled target (out of service, or nothing to do but
    # one rest) sits there in every configuration: locations in conflict with it are out
    forced = [int(r[0]) for k, r in enumerate(rests)
              if len(r) == 1 and a.arm_start[k + 1] - a.arm_start[k] == 1]
    in_pool = np.zeros(inc.reachability.n_targets, bool)
    in_pool[pool] = True
    loc = np.flatnonzero((a.target >= 0) & in_pool[np.maximum(a.target, 0)])
    if forced:
        bad = np.zeros(n_all, bool)
        for f in forced:
            bad[inc.neighbours(f)] = True
        loc = loc[~bad[loc]]
    if len(loc) > MAX_LOCATIONS:
        return None
    loc = loc[np.argsort(a.target[loc], kind="stable")]
    tgt_of_loc = a.target[loc]
    arm_of_loc = a.arm[loc].astype(np.int64)
    # local target numbering: pool order
    local_t = np.full(inc.reachability.n_targets, -1, np.int64)
    local_t[pool] = np.arange(len(pool))
    lt = local_t[tgt_of_loc]
    start = np.searchsorted(lt, np.arange(len(pool) + 1))
    if (start[1:] == start[:-1]).any():
        return None  # a pooled target has no usable location
    n_loc = len(loc)
    # dense conflict matrix over the candidate locations: incompatible pairs + same arm
    glob2loc = np.full(n_all, -1, np.int64)
    glob2loc[loc] = np.arange(n_loc)
    conflict = conflict_adjacency(inc)[loc][:, loc].toarray().astype(bool)
    conflict |= arm_of_loc[:, None] == arm_of_loc[None, :]
    np.fill_diagonal(conflict, False)
    conf_i = conflict.astype(np.int32)  # rows added to / subtracted from the count columns
    clock.charge(TABU_CELL_S * n_loc * n_loc)

    occ = np.full((n_configs, n_arms), -1, np.int64)  # local location per (configuration, arm)
    where = np.full(len(pool), -1, np.int64)  # configuration of each pooled target
    # per (location, configuration): the weight of the placed targets it conflicts with
    # stored per configuration (rows), so that placing or removing a target updates one
    # contiguous row
    gamma = np.zeros((n_configs, n_loc), np.int64)
    n_hit = np.zeros((n_configs, n_loc), np.int32)  # and how many they are
    tabu = np.zeros((n_configs, len(pool)), np.int64)  # per configuration: tabu until
    weight = np.ones(len(pool), np.int64)  # grows while a target stays unplaced
    placed_w = np.zeros(len(pool), np.int64)

    def put(i: int, c: int) -> None:
        t = lt[i]
        occ[c, arm_of_loc[i]] = i
        where[t] = c
        placed_w[t] = weight[t]
        gamma[c] += placed_w[t] * conf_i[i]
        n_hit[c] += conf_i[i]

    def take(i: int, c: int) -> None:
        t = lt[i]
        occ[c, arm_of_loc[i]] = -1
        where[t] = -1
        gamma[c] -= placed_w[t] * conf_i[i]
        n_hit[c] -= conf_i[i]

    def start_from(use_hint: bool) -> None:
        occ.fill(-1)
        where.fill(-1)
        gamma.fill(0)
        n_hit.fill(0)
        tabu.fill(0)
        weight.fill(1)
        if use_hint and hint:
            counts = [int(in_pool[np.maximum(a.target[h], 0)][a.target[h] >= 0].sum()) for h in hint]
            for c, j in enumerate(np.argsort(counts, kind="stable")[::-1][:n_configs]):
                for g in np.asarray(hint[j]):
                    i = int(glob2loc[int(g)])
                    if i >= 0 and where[lt[i]] < 0 and n_hit[c, i] == 0:
                        put(i, c)
        for t in rng.permutation(len(pool)):  # greedy completion of the start
            if where[t] >= 0:
                continue
            rows = np.arange(start[t], start[t + 1])
            free = np.argwhere(n_hit[:, rows].T == 0)
            if len(free):
                r, c = free[rng.integers(len(free))]
                put(int(rows[r]), int(c))

    start_from(True)

    def blocked_by(assignments: np.ndarray) -> np.ndarray:
        """(n_assignments,) bool: the locations in conflict with any of ``assignments``."""
        mask = np.zeros(n_all, bool)
        for g in assignments:
            mask[inc.neighbours(int(g))] = True
        return mask

    def rest_violations() -> tuple[int, np.ndarray] | None:
        """The first configuration whose idle arms cannot all rest, with the local
        locations to eject; None when every configuration can rest its idle arms."""
        for c in range(n_configs):
            placed = loc[occ[c][occ[c] >= 0]]
            idle = [k for k in range(n_arms) if occ[c, k] < 0]
            choice = _choose_rests(inc, [rests[k] for k in idle], blocked_by(placed))
            if choice is None:
                # eject the blockers of the rest location with the fewest (but some), of an
                # idle arm with no free rest first (an arm with a free rest is not the problem)
                best = None
                for k in idle:
                    hits = [occ[c][(occ[c] >= 0)][blocked_by([r])[placed]] for r in rests[k]]
                    free = any(len(h) == 0 for h in hits)
                    for h in hits:
                        if len(h) and (best is None or (free, len(h)) < best[0]):
                            best = ((free, len(h)), h)
                return c, (best[1] if best is not None else np.zeros(0, np.int64))
        return None

    def result() -> list[np.ndarray]:
        out = []
        for c in range(n_configs):
            ch = np.full(n_arms, -1, np.int64)
            placed = occ[c] >= 0
            ch[placed] = loc[occ[c][placed]]
            idle = np.flatnonzero(~placed)
            ch[idle] = _choose_rests(inc, [rests[k] for k in idle], blocked_by(ch[placed]))
            out.append(ch)
        return out

    def give_up() -> None:
        if partial_out is not None:
            o = best_partial[1]
            partial_out[:] = [loc[o[c][o[c] >= 0]] for c in range(n_configs)]

    rows_of = [np.arange(start[t], start[t + 1]) for t in range(len(pool))]
    BIG = np.iinfo(np.int64).max // 2
    unplaced = int((where < 0).sum())
    best_unplaced = best_ever = unplaced
    best_partial: list = [unplaced, occ.copy()]
    it = last_gain = 0
    if stats is None:
        stats = {}
    stats["restarts"] = 0
    while True:
        stats["iterations"], stats["best_unplaced"] = it, min(best_ever, best_unplaced)
        if restart_after and it - last_gain > restart_after:
            # stuck: the searches that succeed do so within a few thousand moves, so a
            # fresh random start (no hint) beats more of the same
            best_ever = min(best_ever, best_unplaced)
            start_from(False)
            unplaced = best_unplaced = int((where < 0).sum())
            last_gain = it
            stats["restarts"] += 1
        if unplaced == 0:
            bad = rest_violations()
            if bad is None:
                return result()
            c, hit = bad
            if not len(hit):
                return give_up()  # an idle arm with no rest at all: nothing the search can change
            for i in hit:
                take(int(i), c)
            unplaced = int((where < 0).sum())
            # rest conflicts are not in the move costs: a longer tenure keeps the search
            # from putting the same targets straight back
            tabu[c, lt[hit]] = it + 10 + int(0.6 * unplaced) + int(rng.integers(0, 10))
        it += 1
        if (max_iterations is not None and it > max_iterations) or \
                (it % 128 == 0 and clock.now() - t0 > time_limit_s):
            return give_up()
        u = np.flatnonzero(where < 0)
        rows = np.concatenate([rows_of[t] for t in u]) if len(u) > 1 else rows_of[u[0]]
        tl = lt[rows]
        # per (configuration, candidate location); weighted: targets that keep ending up
        # unplaced become expensive to eject
        cost = gamma[:, rows] - weight[tl][None, :] if weighting else n_hit[:, rows].astype(np.int64)
        is_tabu = tabu[:, tl] > it
        if unplaced - 1 < best_unplaced:  # aspiration: a free location gives a new best
            is_tabu &= n_hit[:, rows] != 0
        cost[is_tabu] = BIG
        clock.charge(TABU_MOVE_S + TABU_CELL_S * (cost.size + 2 * n_loc))
        low = cost.min()
        if low >= BIG:
            continue  # everything tabu: let the tenures run out
        cand = np.flatnonzero((cost == low).T)  # candidate-major, as the moves are listed
        r, c = divmod(int(cand[rng.integers(len(cand))]), n_configs)
        i = int(rows[r])
        ejected = occ[c][(occ[c] >= 0)]
        ejected = ejected[conflict[i, ejected]]
        for e in ejected:
            take(int(e), c)
        put(i, c)
        unplaced += len(ejected) - 1
        tenure = int(0.6 * unplaced) + int(rng.integers(0, 10))
        tabu[c, lt[ejected]] = it + tenure
        if unplaced < best_unplaced:
            best_unplaced, last_gain = unplaced, it
            if partial_out is not None and unplaced < best_partial[0]:
                best_partial[0], best_partial[1] = unplaced, occ.copy()
        if weighting:
            weight[where < 0] += 1


def _choose_rests(inc: Incompatibility, options: list[np.ndarray], blocked: np.ndarray,
                  max_nodes: int = 5000) -> np.ndarray | None:
    """One rest location per idle arm (``options[i]``: that arm's rest locations), none in
    ``blocked`` and no two incompatible — depth-first, fewest options first, at most
    ``max_nodes`` tried (None then, as when there is none)."""
    opts = [o[~blocked[o]] for o in options]
    if any(len(o) == 0 for o in opts):
        return None
    order = sorted(range(len(opts)), key=lambda i: len(opts[i]))
    pick = np.full(len(opts), -1, np.int64)
    nodes = [0]

    def dfs(d: int, banned: frozenset) -> bool:
        if d == len(order):
            return True
        i = order[d]
        for r in opts[i]:
            nodes[0] += 1
            if nodes[0] > max_nodes:
                return False
            if int(r) in banned:
                continue
            pick[i] = r
            if dfs(d + 1, banned | frozenset(inc.neighbours(int(r)).tolist())):
                return True
        return False

    return pick if dfs(0, frozenset()) else None
