"""Repair pass for a configuration sequence: empty the under-filled tail by ejection moves.

One-at-a-time sequencing (thesis 5.4) maximises priority per configuration, so a crowded
spot's lowest-priority targets can only be observed in the last configurations — near the
FOV centre only one arm fits at a time, and each of them then fills a configuration of its
own.  The CP-SAT repacking of :mod:`solvers.sequencing` works on a suffix of the sequence
and cannot fix this when the earlier configurations are needed too.  This pass works on the
whole sequence with the precomputed incompatibility structure only (no geometry calls):

* **insert**: a target goes to another configuration where an arm that reaches it is
  idle (at a rest location) and the new assignment conflicts with none of the other arms;
* **ejection chain**: a target takes an arm that is observing another target ``u`` (the
  new assignment compatible with the other arms), ``u`` does the same elsewhere, ... until
  one lands on an idle arm — the shortest such chain, breadth-first over targets, through
  distinct configurations (so each step, checked on the unchanged configuration, stays
  valid when the whole chain is applied).

A configuration is removed when every target in it found a new home (all or nothing).
Configurations are tried fewest targets first; among the targets a chain could displace,
the lowest-priority ones come first (then the latest configuration), so high-priority
targets stay in the early configurations, and the result is sorted by total priority.
Every move keeps each configuration valid under eqs. 5.13–5.15; the caller still
re-verifies every changed configuration geometrically.
"""

from __future__ import annotations

import numpy as np

from models import clock
from models.incompatibility import Incompatibility
from solvers.effort import REPAIR_STEP_S

__all__ = ["absorb_configurations"]


class _Sequence:
    """The sequence as an (n_configs, n_arms) matrix of assignment indices, plus lookups."""

    def __init__(self, inc: Incompatibility, chosen: list[np.ndarray]):
        a = inc.assignments
        self.a = a
        self.n_arms = len(a.arm_start) - 1
        self.C = np.array(chosen, np.int64).reshape(len(chosen), self.n_arms)
        self.indices, self.indptr = inc.indices, inc.indptr  # the structure's CSR adjacency
        real = np.flatnonzero(a.target >= 0)
        order = real[np.argsort(a.target[real], kind="stable")]
        self._by_target = order
        self._start = np.searchsorted(a.target[order], np.arange(inc.reachability.n_targets + 1))
        self._rows: dict[int, np.ndarray] = {}

    def assignments_of(self, t: int) -> np.ndarray:
        return self._by_target[self._start[t]:self._start[t + 1]]

    def conflict_row(self, x: int) -> np.ndarray:
        """(n_assignments,) bool: the locations in conflict with ``x`` (cached: chain
        searches visit the same assignments again and again)."""
        row = self._rows.get(x)
        if row is None:
            row = np.zeros(len(self.a), bool)
            row[self.indices[self.indptr[x]:self.indptr[x + 1]]] = True
            self._rows[x] = row
        return row

    def fits(self, x: int, rows: np.ndarray) -> np.ndarray:
        """Configurations ``rows`` in which arm(x) may take assignment ``x``: no conflict with
        the other arms' assignments (arm(x)'s own entry is replaced, so it is ignored)."""
        k = int(self.a.arm[x])
        bad = self.conflict_row(x)[self.C[rows]]
        bad[:, k] = False
        return ~bad.any(axis=1)


def absorb_configurations(inc: Incompatibility, chosen: list[np.ndarray], priority: np.ndarray, *, budget_s: float,
                          loose: list[np.ndarray] | None = None, min_keep: int = 0,
                          max_failures: int = 3) -> tuple[list[np.ndarray], list[bool]]:
    """Empty configurations of ``chosen`` (per configuration, the (n_arms,) assignment
    indices) by moving their targets into the others; ``loose`` target groups (e.g. the
    rescue configurations, built on another structure) are absorbed the same way, all of a
    group or none.  Stops at ``budget_s``, when ``min_keep`` configurations are left, or
    after ``max_failures`` configurations in a row could not be emptied.

    Returns the new list (emptied configurations removed, the rest sorted by total
    priority, highest first, as one-at-a-time sequencing orders them) and, per ``loose``
    group, whether it was absorbed.
    """
    t0 = clock.now()
    s = _Sequence(inc, chosen)
    a = s.a
    # configurations only ever gain targets (on idle arms, checked against every other
    # arm, rests included) or swap one target for another on the same arm, so no rest
    # location becomes invalid; only the emptied configurations disappear
    is_rest = a.target < 0
    prio = np.asarray(priority, np.int64)
    n_targets = inc.reachability.n_targets
    alive = np.ones(len(s.C), bool)
    groups = list(loose or [])
    absorbed = [False] * len(groups)

    def place(t: int, exclude: np.ndarray) -> list[tuple[int, int, int]] | None:
        """The shortest ejection chain that gives target ``t`` a home outside the
        ``exclude`` configurations: t takes (c1, k1) from v1, v1 takes (c2, k2) from v2,
        ..., the last one an idle arm.  Breadth-first over targets; the configurations of a
        chain are distinct, so every step, checked against the unchanged configuration,
        stays valid when the whole chain is applied.  Applied to s.C and returned as moves
        (config, arm, previous assignment); None (nothing applied) if there is none."""
        base = alive & ~exclude
        parent: dict[int, tuple[int, int, int, int] | None] = {t: None}  # v: (prev, c, k, x)
        seen = np.zeros(n_targets, bool)
        seen[t] = True
        on_path: dict[int, tuple[int, ...]] = {t: ()}
        frontier = [t]
        while frontier:
            if clock.now() - t0 > budget_s:
                return None
            nxt = []
            clock.charge(len(frontier) * REPAIR_STEP_S)
            for v in frontier:
                m = base.copy()
                m[list(on_path[v])] = False
                rows_all = np.flatnonzero(m)
                if not len(rows_all):
                    continue
                cand = []
                for x in s.assignments_of(v):
                    x = int(x)
                    k = int(a.arm[x])
                    ok = rows_all[s.fits(x, rows_all)]
                    idle = ok[is_rest[s.C[ok, k]]]
                    if len(idle):  # a home: apply the chain back to t
                        c = int(idle[-1])  # the latest configuration: keeps the priority order
                        moves = [(c, k, int(s.C[c, k]))]
                        s.C[c, k] = x
                        w = v
                        while parent[w] is not None:
                            prev, c, k, x = parent[w]
                            moves.append((c, k, int(s.C[c, k])))
                            s.C[c, k] = x
                            w = prev
                        return moves
                    us = a.target[s.C[ok, k]]
                    new = ~seen[us]
                    if new.any():
                        cand.append((prio[us[new]], ok[new], us[new], np.full(int(new.sum()), k), np.full(int(new.sum()), x)))
                if not cand:
                    continue
                pr_, c_, u_, k_, x_ = (np.concatenate(z) for z in zip(*cand, strict=True))
                # the lowest-priority targets are displaced first (then the latest)
                for i in np.lexsort((-c_, pr_)).tolist():
                    u = int(u_[i])
                    if not seen[u]:
                        seen[u] = True
                        parent[u] = (v, int(c_[i]), int(k_[i]), int(x_[i]))
                        on_path[u] = on_path[v] + (int(c_[i]),)
                        nxt.append(u)
            frontier = nxt
        return None

    def undo(moves: list[tuple[int, int, int]]) -> None:
        for c, k, old in reversed(moves):
            s.C[c, k] = old

    def relocate(targets: np.ndarray, exclude: np.ndarray) -> list | None:
        done: list = []
        for t in targets:
            if clock.now() - t0 > budget_s:
                undo(done)
                return None
            mv = place(int(t), exclude)
            if mv is None:
                undo(done)
                return None
            done += mv
        return done

    for g, targets in enumerate(groups):
        if relocate(np.asarray(targets, np.int64), np.zeros(len(s.C), bool)) is not None:
            absorbed[g] = True
    tried = np.zeros(len(s.C), bool)
    failures = 0  # in a row: the sparsest configurations are the easiest to empty
    while alive.sum() > min_keep and failures < max_failures and clock.now() - t0 < budget_s:
        yields = np.where(alive & ~tried, (~is_rest[s.C]).sum(axis=1), np.iinfo(np.int64).max)
        if yields.min() == np.iinfo(np.int64).max:
            break
        # fewest targets first, the latest among equals
        victim = int(np.flatnonzero(yields == yields.min())[-1])
        tried[victim] = True
        ch = s.C[victim]
        exclude = np.zeros(len(s.C), bool)
        exclude[victim] = True
        if relocate(a.target[ch[~is_rest[ch]]], exclude) is not None:
            alive[victim] = False
            tried[:] = False  # homes have changed: earlier failures may succeed now
            failures = 0
        else:
            failures += 1
    out = [s.C[c].copy() for c in np.flatnonzero(alive)]
    tp = [-sum(int(priority[t]) for t in a.target[ch] if t >= 0) for ch in out]
    order = np.argsort(tp, kind="stable")
    return [out[i] for i in order], absorbed
