"""SGPBTA construction and padding (thesis Algorithms 4 and 5): the limited pool of
candidates, the patrol-ordered arm choice (GAS / PBAS) and the padding of idle arms."""

from __future__ import annotations

from typing import Literal

import numpy as np

from solvers.allocation.semigreedy.prepare import Prepared, State

ArmSelection = Literal["gas", "pbas"]


# ------------------------------------------------------------ construction (Alg. 4)


def lpc(eta: np.ndarray, candidates: np.ndarray, alpha: float) -> np.ndarray:
    """Limited pool of candidates (eq. 5.5): those with eta >= eta_max - alpha (eta_max - eta_min)."""
    e = eta[candidates]
    hi, lo = e.max(), e.min()
    q = hi - alpha * (hi - lo)
    return candidates[e >= q - 1e-12 * max(1.0, abs(hi))]


def construct(st: Prepared, alpha: float, arm_selection: ArmSelection, rng: np.random.Generator,
              lookahead: bool = True) -> State:
    """Semi-greedy patrol-based construction (thesis Algorithm 4), vectorised.

    ``cnt[t]`` counts the assignments of live target t still usable (arm free, not
    blocked by any assignment made); a target with ``cnt == 0`` is left out of the pool:
    in the thesis it would be drawn, fail every arm (line 13) and land in T^o (line 19)
    with no other effect. Live ids are sorted by decreasing eta, so the pool of eq. 5.5
    is the live part of a prefix. The candidate list of the drawn target holds only
    usable assignments, so the first arm in GAS/PBAS order is the one lines 10-18 accept.

    ``lookahead`` (a departure, default on): a candidate is accepted only if every arm
    still without a location keeps at least one compatible rest location (current, park,
    blank sky), so padding (Algorithm 5) cannot fail; in the thesis such a solution is
    built, fails padding and is dropped (Algorithm 3, line 9). Off: Algorithm 4 verbatim.
    """
    s = State.empty(st)
    m = len(st.eta)
    if m == 0:
        return s
    blocked, chosen = s.blocked, s.chosen
    arm, arm_l, tok, tc = st.arm, st.arm_l, st.tok, st.tc
    indptr_l, indices, rn_ptr, rn_idx, rn_arm = st.indptr_l, st.indices64, st.rn_ptr_l, st.rn_idx, st.rn_arm
    tasg_l, tptr_l, pen_l, arm_start_l = st.tasg_l, st.tptr_l, st.pen_l, st.arm_start_l
    n_arms = st.n_arms
    eta = st.eta
    neg_eta = -eta
    tol = 1e-12 * max(1.0, abs(float(eta[0])))
    arm_free = (chosen < 0) & st.target_arms
    arm_free_l = arm_free.tolist()
    n_free = int(arm_free.sum())
    idle = chosen < 0  # arms without a location yet (they will need a rest location)
    elig = tok & arm_free[arm]  # target assignments of free arms (usable unless blocked)
    cnt = st.cnt0.copy()
    live = cnt > 0  # drawable: not drawn yet and still some usable assignment
    rest_free = st.rest_free0.copy()
    pbas = arm_selection == "pbas"
    # uniform draws in batches (one Generator call per 64 draws)
    buf = rng.random(64).tolist()
    first, last, end = 0, m - 1, -1  # live ids are sorted by decreasing eta

    while n_free:
        if not live[first]:
            first += int(live[first:].argmax())
            if not live[first]:
                break
            end = -1
        if not live[last]:
            last -= int(live[last::-1].argmax())
            end = -1
        if end < 0:  # the pool bound of eq. 5.5 moves only with the live extremes
            hi = eta[first]
            q = hi - alpha * (hi - eta[last])
            end = int(np.searchsorted(neg_eta, -q + tol, side="right"))
        # a uniform draw from the live ids in [first, end): rejection sampling (exact), the
        # explicit list only when live ids are sparse in the window
        t = -1
        for _ in range(4):
            if not buf:
                buf = rng.random(64).tolist()
            j = first + int(buf.pop() * (end - first))
            if live[j]:
                t = j
                break
        if t < 0:
            pool = np.flatnonzero(live[first:end])
            if not buf:
                buf = rng.random(64).tolist()
            t = first + int(pool[int(buf.pop() * len(pool))])
        live[t] = False
        s.picked.append(t)
        cand = [x for x in tasg_l[tptr_l[t]:tptr_l[t + 1]] if arm_free_l[arm_l[x]] and not blocked[x]]
        if pbas and len(cand) > 1:
            # PBAS: per penalty level, the arms in random order (each arm's assignments keep
            # their displacement order: the sort is stable); GAS keeps penalty, arm, displacement
            ks = {arm_l[c] for c in cand}
            if len(ks) > 1:
                if len(buf) < len(ks):
                    buf += rng.random(64).tolist()
                r = {k: buf.pop() for k in sorted(ks)}
                cand.sort(key=lambda c: (pen_l[c], r[arm_l[c]]))
        # the first candidate that leaves every idle arm a rest location (departure from
        # the thesis: there a solution whose padding fails is dropped at Alg. 3 line 9)
        x = -1
        lost_rest = None
        for c in cand:
            k = arm_l[c]
            r0, r1 = rn_ptr[c], rn_ptr[c + 1]
            if r0 == r1:
                x = c
                break
            lost_rest = np.bincount(rn_arm[r0:r1][blocked[rn_idx[r0:r1]] == 0], minlength=n_arms)
            if lookahead:
                starved = (lost_rest > 0) & (lost_rest >= rest_free) & idle
                starved[k] = False
                if starved.any():
                    lost_rest = None
                    continue
            x = c
            break
        if x < 0:
            continue
        k = arm_l[x]
        s0, s1 = arm_start_l[k], arm_start_l[k + 1]
        lost = elig[s0:s1] & (blocked[s0:s1] == 0)  # arm k's usable assignments go away
        dec = tc[s0:s1][lost]
        elig[s0:s1] = False
        arm_free_l[k] = False
        idle[k] = False
        n_free -= 1
        if lost_rest is not None:
            rest_free -= lost_rest
        nb = indices[indptr_l[x]:indptr_l[x + 1]]
        bnb = blocked[nb]
        free_nb = bnb == 0
        blocked[nb] = bnb + 1
        chosen[k] = x
        dec2 = tc[nb[free_nb & elig[nb]]]  # usable assignments of other free arms now blocked
        for d in (dec, dec2):
            if len(d):
                np.subtract.at(cnt, d, 1)
                live[d[cnt[d] == 0]] = False
    return s


# ------------------------------------------------------------------ padding (Alg. 5)


def pad(st: Prepared, s: State) -> bool:
    """Solution padding (thesis Algorithm 5): each arm left without a target goes to the
    first compatible rest location in the order current position, park, blank sky.

    Blank-sky locations are the ones sampled in the free area in front of each arm
    (``models.incompatibility.sample_blank_sky``, target ``BLANK``) when the structure
    was built with ``blank_per_arm``; they are tried by increasing displacement (the
    thesis samples the area at random; the sample is already random, and the shorter
    move is what the solution update prefers). All are locations of the structure, so
    compatibility is the same ``blocked == 0`` test and padding can never collide. The
    pending arms are placed jointly (:func:`_pad_search`, most constrained arm first), since
    one arm's blank-sky location may take a neighbour's last free one.

    Last resort (no blank-sky sample fits, or the structure has none): the assignments
    blocking the arm's preferred rest location are undone and their arms padded in turn
    -- where the thesis would return an incomplete solution and drop the iteration. It
    keeps every iteration complete; the local search can re-fill those arms. Returns
    False only if no complete solution was reached.
    """
    pending = [int(k) for k in np.flatnonzero(s.chosen < 0)]
    for k in [k for k in pending if st.rest_ptr[k] == st.rest_ptr[k + 1]]:
        # an arm with no rest location at all: any compatible location of it
        sl = np.arange(int(st.arm_start[k]), int(st.arm_start[k + 1]))
        ok = sl[st.movable[sl] & (s.blocked[sl] == 0)]
        if not len(ok):
            return False
        s.place(st, int(ok[0]))
        pending.remove(k)
    for _ in range(4 * st.n_arms):
        if not pending or _pad_search(st, s, pending):
            return True
        # last resort: undo the target assignment that blocks the most rest locations of
        # the pending arms (the lowest priority among equals); its arm is padded in turn
        busy = [int(j) for j in np.flatnonzero((s.chosen >= 0) & (st.preset < 0)) if st.is_target[s.chosen[j]]]
        pend_arm = np.zeros(st.n_arms, bool)
        pend_arm[pending] = True
        best = None
        for j in busy:
            c = int(s.chosen[j])
            rn = st.rn_idx[st.rn_ptr[c]:st.rn_ptr[c + 1]]
            hits = int(pend_arm[st.arm[rn]].sum())
            if hits and (best is None or (-hits, int(st.prio[c])) < best[0]):
                best = ((-hits, int(st.prio[c])), j)
        if best is None:  # only out-of-service arms or rest locations in the way
            return False
        s.remove(st, best[1])
        pending.append(best[1])
    return not pending


def _pad_search(st: Prepared, s: State, pending: list[int], max_nodes: int = 2000) -> bool:
    """Place every pending arm on a free rest location jointly (depth-first, most
    constrained arm first, each arm's options in padding order). On success the arms are
    placed and True is returned; on failure ``s`` is left unchanged."""
    order, ptr, blocked = st.rest_order, st.rest_ptr, s.blocked
    placed: list[int] = []
    nodes = 0

    def dfs(left: list[int]) -> bool:
        nonlocal nodes
        if not left:
            return True
        frees = [order[ptr[j]:ptr[j + 1]][blocked[order[ptr[j]:ptr[j + 1]]] == 0] for j in left]
        i = min(range(len(left)), key=lambda q: len(frees[q]))
        rest = left[:i] + left[i + 1:]
        for r in frees[i].tolist():
            nodes += 1
            if nodes > max_nodes:
                return False
            s.place(st, r)
            placed.append(left[i])
            if dfs(rest):
                return True
            s.remove(st, placed.pop())
        return False

    if dfs(list(pending)):
        pending.clear()
        return True
    return False


# ------------------------------------------------------------- local search (5.3.1.3)
