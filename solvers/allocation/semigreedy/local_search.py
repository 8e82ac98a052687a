"""SGPBTA local search (thesis 5.3.1.3): swap and replace moves, first improvement, and
the ejection moves (a departure: an idle arm takes a target blocked by one or two chosen
locations whose arms move elsewhere)."""

from __future__ import annotations

import numpy as np

from models import clock
from solvers.allocation.semigreedy.prepare import DISP_EPS, Prepared, State
from solvers.effort import SEMIGREEDY_PASS_S


def swap_pass(st: Prepared, s: State, rng: np.random.Generator) -> bool:
    """One first-improvement pass of swap moves; True if a move was made.

    Two arms on targets exchange them (each arm must patrol the other's target). Priority
    and yield are unchanged, so a swap can only shorten the total displacement. Pairs of
    adjacent arms are tried first, the others in random order (thesis 5.3.1.3).
    """
    chosen = s.chosen
    on_target = chosen[chosen >= 0]
    on_target = on_target[st.tc[on_target] >= 0]
    if len(on_target) < 2:
        return False
    # x2: an assignment of another busy arm k2 on the target held by k1
    lists = [st.tasg[st.tptr[t]:st.tptr[t + 1]] for t in st.tc[on_target]]
    x2s = np.concatenate(lists)
    holder = np.repeat(st.arm[on_target], [len(v) for v in lists])
    k2s = st.arm[x2s]
    c2s = chosen[k2s]
    # x2's only blocker must be the holder of its target (same-target conflict)
    keep = (k2s != holder) & (c2s >= 0) & (s.blocked[x2s] == 1)
    keep[keep] &= st.tc[c2s[keep]] >= 0
    if not keep.any():
        return False
    x2s, k1s, k2s = x2s[keep], holder[keep], k2s[keep]
    n = st.n_arms
    dist = np.minimum((k1s - k2s) % n, (k2s - k1s) % n)
    order = np.lexsort((rng.random(len(x2s)), dist > 1))
    disp, blocked = st.disp, s.blocked
    for i in order.tolist():
        k1, k2, x2 = int(k1s[i]), int(k2s[i]), int(x2s[i])
        c1, c2 = int(chosen[k1]), int(chosen[k2])
        t2 = int(st.tc[c2])
        for x1 in st.tasg[st.tptr[t2]:st.tptr[t2 + 1]].tolist():
            if arm_of(st, x1) != k1 or blocked[x1] != 1:
                continue
            if disp[x1] + disp[x2] - disp[c1] - disp[c2] >= -DISP_EPS:
                continue
            nb = st.indices[st.indptr[x1]:st.indptr[x1 + 1]]
            j = int(np.searchsorted(nb, x2))
            if j < len(nb) and nb[j] == x2:
                continue
            s.remove(st, k1)
            s.remove(st, k2)
            s.place(st, x1)
            s.place(st, x2)
            return True
    return False


def arm_of(st: Prepared, x: int) -> int:
    return int(st.arm[x])


def replace_pass(st: Prepared, s: State, rng: np.random.Generator) -> int:
    """One pass of replace moves over the arms in random order; returns #moves made.

    An arm moves to another location (a pending target it patrols, or a rest location)
    compatible with the others. First improvement over arms: each arm whose
    neighbourhood holds an improving move is moved at once and the scan goes on; within
    one arm all its replacements are scored in one vectorised step, so the best of them
    (priority, then displacement; yield follows priority since targets have p >= 1) is
    taken -- it costs the same as the first. The thesis restricts the new target to the
    arm's own and adjacent slices; here any slice the penalty matrix allows is taken.
    """
    score = np.where(st.movable & (s.blocked == 0), st.score, -np.inf)
    chosen = s.chosen
    # arms whose best compatible location beats the current one (the float score ranks
    # exactly as (priority, -displacement) up to DISP_EPS): the others have no move, and
    # the moves of other arms in this pass only block locations, never free better ones...
    # except the location an arm leaves, hence the rescan of arms after a move
    busy = chosen >= 0
    cur = np.where(busy, st.score[np.maximum(chosen, 0)], np.inf)
    best = np.maximum.reduceat(score, st.arm_start[:-1]) if len(score) else np.full(st.n_arms, -np.inf)
    best[np.diff(st.arm_start) == 0] = -np.inf
    if not ((best > cur) & (st.preset < 0)).any():
        return 0
    made = 0
    arm_start = st.arm_start_l
    for k in rng.permutation(st.n_arms).tolist():
        c = int(chosen[k])
        if c < 0 or st.preset[k] >= 0:
            continue
        if not made and not best[k] > cur[k]:
            continue
        s0, s1 = arm_start[k], arm_start[k + 1]
        if made:  # earlier moves of this pass changed what is blocked
            sc = np.where(st.movable[s0:s1] & (s.blocked[s0:s1] == 0), st.score[s0:s1], -np.inf)
        else:
            sc = score[s0:s1]
        j = s0 + int(sc.argmax())
        if j == c:
            continue
        # exact lexicographic check (the float score only ranks)
        dp = int(st.prio[j]) - int(st.prio[c])
        dh = int(st.hw[j]) - int(st.hw[c])
        if dp > 0 or (dp == 0 and (dh > 0 or (dh == 0 and st.disp[j] < st.disp[c] - DISP_EPS))):
            s.remove(st, k)
            s.place(st, j)
            made += 1
    return made


def _better(dp: int, dy: int, dh: int, dd: float) -> bool:
    """A change (priority, yield, tie-break weight, displacement) improves the key."""
    if dp or dy or dh:
        return (dp, dy, dh) > (0, 0, 0)
    return dd < -DISP_EPS


def eject_pass(st: Prepared, s: State, rng: np.random.Generator, max_blockers: int = 2,
               max_trials: int = 24) -> int:
    """Ejection moves (a departure, beyond the swap and replace moves of 5.3.1.3).

    An arm at rest takes a target location ``x`` blocked by at most ``max_blockers``
    chosen locations of other arms; each of those arms moves, in turn, to its best location
    (score order: priority, tie-break weight, displacement) compatible with the others and
    ``x``. Kept if the solution key improves, undone otherwise. A replace move cannot do
    it: ``x`` is free only once its blockers have left, and a blocker leaving alone
    usually loses something. In the under-filled tail of a sequence the idle arms' rest
    locations and the few arms on targets block the last targets (e.g. a rim target whose
    arm collides with both neighbours' blank-sky rests); this is the move that frees them.
    First improvement; returns #moves (0 or 1).
    """
    chosen = s.chosen
    n = st.n_arms
    idle = [k for k in range(n) if chosen[k] >= 0 and st.preset[k] < 0 and not st.is_target[chosen[k]]
            and st.target_arms[k]]
    if not idle:
        return 0
    blocked = s.blocked
    cands = []
    for k in idle:
        s0, s1 = st.arm_start_l[k], st.arm_start_l[k + 1]
        b = blocked[s0:s1]
        cands.append(s0 + np.flatnonzero(st.tok[s0:s1] & (b >= 1) & (b <= max_blockers)))
    xs = np.concatenate(cands)
    if not len(xs):
        return 0
    owner = np.full(len(blocked), -1, np.intp)
    placed = chosen >= 0
    owner[chosen[placed]] = np.flatnonzero(placed)
    order = np.lexsort((rng.random(len(xs)), -st.score[xs]))
    indices, indptr_l, arm_start_l = st.indices64, st.indptr_l, st.arm_start_l
    prio, is_t, hw, disp = st.prio, st.is_target, st.hw, st.disp
    arm_l, movable, score = st.arm_l, st.movable, st.score

    def prio_l(c: int) -> int:
        return int(prio[c])

    for x in xs[order].tolist():
        k = st.arm_l[x]
        js = owner[indices[indptr_l[x]:indptr_l[x + 1]]]
        js = js[js >= 0].tolist()
        if len(js) > max_blockers or k in js or any(st.preset[j] >= 0 for j in js):
            continue
        if max_trials <= 0:
            break
        max_trials -= 1
        # evaluate without touching the state: each blocker's new blocking counts on its
        # own slice = now - (rows of the locations left) + (rows of the locations taken)
        old = [int(chosen[k])] + [int(chosen[j]) for j in js]
        new = [x]
        for j in js:
            s0, s1 = arm_start_l[j], arm_start_l[j + 1]
            b = blocked[s0:s1].copy()
            for c in old:
                if arm_l[c] != j:  # an arm's own locations never block each other
                    b[_row_in(st, c, s0, s1)] -= 1
            for c in new:
                b[_row_in(st, c, s0, s1)] += 1
            sc = np.where(movable[s0:s1] & (b == 0), score[s0:s1], -np.inf)
            y = int(sc.argmax())
            if sc[y] == -np.inf:
                break
            new.append(s0 + y)
        if len(new) < len(old):
            continue
        dp = sum(prio_l(c) for c in new) - sum(prio_l(c) for c in old)
        dy = sum(is_t[c] for c in new) - sum(is_t[c] for c in old)
        dh = sum(int(hw[c]) for c in new) - sum(int(hw[c]) for c in old)
        dd = sum(float(disp[c]) for c in new) - sum(float(disp[c]) for c in old)
        if _better(int(dp), int(dy), dh, dd):
            for j in [k] + js:
                s.remove(st, j)
            for y in new:
                s.place(st, y)
            return 1
    return 0


def _row_in(st: Prepared, c: int, s0: int, s1: int) -> np.ndarray:
    """The assignments in [s0, s1) incompatible with ``c``, as offsets from s0 (CSR rows are sorted)."""
    nb = st.indices64[st.indptr_l[c]:st.indptr_l[c + 1]]
    return nb[nb.searchsorted(s0):nb.searchsorted(s1)] - s0


def local_search(st: Prepared, s: State, rng: np.random.Generator, max_moves: int = 1000,
                 swaps: bool = True, eject_trials: int = 0) -> int:
    """Swap moves to a local optimum, then replace moves, repeated until neither improves
    (thesis 5.3.1.3), then ejection moves (:func:`eject_pass`, a departure) when those find
    nothing. Every move strictly improves the lexicographic key. Returns #moves.
    ``swaps=False``: no swap moves; ``eject_trials``: ejection moves evaluated per pass
    (0: none)."""
    moves = passes = 0
    while moves < max_moves:
        made = 0
        while swaps and moves + made < max_moves and swap_pass(st, s, rng):
            made += 1
        passes += made + (1 if swaps else 0) + 1
        made += replace_pass(st, s, rng)
        if not made and eject_trials > 0:
            passes += 1
            made += eject_pass(st, s, rng, max_trials=eject_trials)
        moves += made
        if not made:  # a replace can enable new swaps: repeat until a quiet round
            break
    clock.charge(passes * SEMIGREEDY_PASS_S)
    return moves
