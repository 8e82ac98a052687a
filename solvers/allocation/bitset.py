"""The bitset branch-and-bound search for one configuration, specialised to the IPBA structure.

Shared by the ``bnb`` back-end (:mod:`solvers.allocation.bnb`) and by the presolve of the
HiGHS and CP-SAT back-ends (:mod:`solvers.allocation.exact`: its incumbent dive and its
proven column pruning).  The integer program of :mod:`solvers.model` has a special shape: 12 arms, each takes exactly
ONE location (eq. 5.13), and every other constraint (5.14 same target, 5.15 collisions) is
a *pairwise* conflict between locations of different arms.  That is a weighted CSP with
12 variables, which a small depth-first branch-and-bound with forward checking solves
exactly and fast:

* each arm's locations are ordered by the coarse weight (priority, then yield) from high
  to low; an arm's *domain* is a Python-int bitset over that order;
* per location ``a`` and other arm ``k'`` a bitset of ``k'``'s locations in conflict with
  ``a`` (built once per field with numpy ``packbits``; priorities do not change between
  the configurations of a sequence, only availability and the tie-break do — stages 2
  and 3 use a small table of their own, ordered by the full weight of the call);
* assigning ``a`` to its arm removes ``a``'s conflicts from every other domain (forward
  checking); an empty domain fails;
* bound = current weight + sum over unassigned arms of the best weight still in their
  domain = the weight of the *lowest set bit*, found in O(1) by ``(d & -d).bit_length()``;
* values are tried best first, so the first dive is a greedy solution and the loop stops
  as soon as ``bound <= incumbent`` (later values weigh no more).

Stage 2 (eq. 5.16, min longest move among maximum-weight solutions) is the same search
with the weight held at the stage-1 optimum and every location whose move is not strictly
shorter than the incumbent's longest move removed, restarted after each improvement.

Exact in Python integers (priorities up to 2^32 - 1).  ``node_limit`` bounds the work;
when it is hit the caller gets the incumbent with status ``feasible`` and a gap against
the largest open bound (or falls back to CP-SAT, see
:func:`solvers.allocation.bnb.solve_ilp_bnb`).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from models import clock
from models.budget import Budget
from solvers.effort import BNB_NODE_S, BNB_TABLE_BIT_S, BNB_TABLE_ROW_S, PRUNE_PROBE_S
from solvers.model import coarse_weights, conflict_adjacency, safe_weights
from solvers.problem import ConfigProblem
from solvers.thread_cache import thread_cache

__all__ = ["BnbField", "consistent", "prepare_field", "prune_columns", "solve_bnb_chosen"]


@dataclass
class BnbField:
    """Per-field, availability-independent tables, ordered by the *coarse* weight
    (priority, then yield).  The optional tie-break is not part of them: the sequencing
    driver refreshes it every configuration (crowding of the pending targets), and
    rebuilding these tables each time cost 12 s of a 20 s dense sequence.  Stage 3 (the
    tie-break) builds a small table of its own over the columns that can still reach the
    coarse optimum (:func:`_tie_tables`)."""

    n_arms: int
    order: list[np.ndarray]  # per arm: assignment indices, coarse weight descending
    pos: np.ndarray  # (n_assignments,) bit position of an assignment in its arm's order
    nconf: list[list[int]]  # per assignment: per arm, ~(bitset of conflicting locations)
    weight_key: bytes
    coarse: list[list[int]]  # per arm: priority * (m + 1) + yield, in order
    target_list: list[int]  # per assignment: target index (< 0 for rest locations)
    target_coarse: np.ndarray  # (n_targets,) coarse weight of an assignment on the target


_CACHE = "bitset.fields"  # thread_cache name: id(inc) -> (weakref to inc, BnbField)


def _pack_tables(adj: sparse.csr_matrix, order: list[np.ndarray]) -> dict[int, list[int]]:
    """Per assignment in ``order`` and per arm ``k'``: ~(bitset over ``order[k']`` of the
    locations in conflict with it) — numpy ``packbits``, one block per arm.  The submatrix
    over ``order`` is extracted once; each packed row becomes a Python int by slicing one
    ``bytes`` object (a numpy row view per int costs several times more)."""
    n_arms = len(order)
    if not n_arms:
        return {}
    perm = np.concatenate(order)
    sub = adj[perm][:, perm].tocsr()
    bounds = np.cumsum([0] + [len(o) for o in order])
    from_bytes = int.from_bytes
    nconf: dict[int, list[int]] = {}
    for k in range(n_arms):
        rows = order[k]
        n_rows = len(rows)
        if not n_rows:
            continue
        block = sub[bounds[k]:bounds[k + 1]].toarray()
        clock.charge(block.size * BNB_TABLE_BIT_S + n_rows * n_arms * BNB_TABLE_ROW_S)
        per_arm = []
        for kk in range(n_arms):
            packed = np.packbits(block[:, bounds[kk]:bounds[kk + 1]], axis=1, bitorder="little")
            nb = packed.shape[1]
            raw = packed.tobytes()
            per_arm.append([~from_bytes(raw[i * nb:(i + 1) * nb], "little") for i in range(n_rows)])
        for i, r in enumerate(rows.tolist()):
            nconf[r] = [p[i] for p in per_arm]
    return nconf


def _adjacency(inc) -> sparse.csr_matrix:
    # built once per structure, shared with the ILP
    return conflict_adjacency(inc)


def prepare_field(problem: ConfigProblem) -> BnbField:
    """Bitset conflict tables for ``problem.incompatibility`` under the coarse weights."""
    inc = problem.incompatibility
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    w = coarse_weights(problem, np.arange(len(a)))
    key = w.tobytes()
    cache = thread_cache(_CACHE)
    hit = cache.get(id(inc))
    if hit is not None and hit[0]() is inc and hit[1].weight_key == key:
        return hit[1]
    order = []
    pos = np.zeros(len(a), np.int64)
    for k in range(n_arms):
        idx = np.arange(a.arm_start[k], a.arm_start[k + 1])
        idx = idx[np.argsort(-w[idx], kind="stable")]
        order.append(idx)
        pos[idx] = np.arange(len(idx))
    by_index = _pack_tables(_adjacency(inc), order)
    nconf: list[list[int]] = [by_index.get(i) for i in range(len(a))]  # type: ignore[misc]
    coarse = [[int(v) for v in w[o]] for o in order]
    n_t = inc.reachability.n_targets
    tgt = a.target
    real = tgt >= 0
    t_coarse = np.zeros(n_t, np.int64)
    np.maximum.at(t_coarse, tgt[real], w[real])
    f = BnbField(n_arms, order, pos, nconf, key, coarse, [int(v) for v in tgt], t_coarse)
    if len(cache) > 8:
        cache.clear()
    cache[id(inc)] = (weakref.ref(inc), f)
    return f


@dataclass
class _TieTables:
    """Stage-3 tables over a column subset, ordered by the full safe weight."""

    order: list[np.ndarray]
    nconf: dict[int, list[int]]
    weights: list[list[int]]
    target_full: np.ndarray


def _tie_tables(problem: ConfigProblem, cols: np.ndarray, w_full: np.ndarray) -> _TieTables:
    a = problem.assignments
    n_arms = len(a.arm_start) - 1
    order = []
    for k in range(n_arms):
        idx = np.flatnonzero(cols[a.arm_start[k]:a.arm_start[k + 1]]) + a.arm_start[k]
        order.append(idx[np.argsort(-w_full[idx], kind="stable")])
    nconf = _pack_tables(_adjacency(problem.incompatibility), order)
    real = a.target >= 0
    t_full = np.zeros(problem.incompatibility.reachability.n_targets, np.int64)
    np.maximum.at(t_full, a.target[real], w_full[real])
    return _TieTables(order, nconf, [[int(v) for v in w_full[o]] for o in order], t_full)


def _mask(bits: np.ndarray) -> int:
    return int.from_bytes(np.packbits(bits, bitorder="little").tobytes(), "little")


class _Limit(Exception):
    pass


def solve_bnb_chosen(problem: ConfigProblem, *, node_limit: int = 200_000, minimize_move: bool = True,
                     budget: Budget | None = None, hint: np.ndarray | None = None,
                     field: BnbField | None = None, tie_node_limit: int = 3_000,
                     move_node_limit: int = 30_000, coarse_optimum: tuple[int, np.ndarray] | None = None) -> dict:
    """The search itself, lexicographic in three exact searches over the same bitsets:

    1. max ``priority * (m + 1) + yield`` (the *coarse* weight) — proven or limit hit;
    2. min longest move (eq. 5.16) among solutions of that coarse weight, within
       ``move_node_limit`` nodes (issue 4's order: priority, yield, longest move);
    3. max full safe weight (adds the optional tie-break) among solutions of that coarse
       weight and longest move, within ``tie_node_limit`` nodes — the tie-break is a packing
       heuristic and its per-arm bound is weak (many arms share the same best targets), so
       it is best effort (``tie_proved``).

    Returns a dict: ``chosen`` (None if infeasible / nothing found), ``weight`` (full),
    ``proved`` (stage 1), ``tie_proved``, ``move_proved``, ``bound`` (coarse root bound
    scaled to full weights), ``nodes``. Every search also stops once ``budget`` (None: no
    limit but the node limits) has expired, checked every 1,024 nodes.
    """
    f = field or prepare_field(problem)
    n_arms = f.n_arms
    allowed = problem.allowed()
    move = problem.move_time_s()
    w_all, _, tie_mult = safe_weights(problem, np.arange(len(problem.assignments)))
    max_tie = int((w_all[allowed] % tie_mult).max(initial=0))
    dom0 = [_mask(allowed[f.order[k]]) for k in range(n_arms)]
    out = {"chosen": None, "weight": 0, "proved": True, "tie_proved": True, "move_proved": True, "bound": 0,
           "nodes": 0}
    if any(d == 0 for d in dom0):
        return out
    state = {"best": -1, "sol": None, "nodes": 0, "limit": 0, "charged": 0}

    def settle() -> None:
        """Charge the nodes searched since the last charge."""
        clock.charge((state["nodes"] - state["charged"]) * BNB_NODE_S)
        state["charged"] = state["nodes"]

    class _Found(Exception):
        pass

    tgt_of = f.target_list

    def run(W: list[list[int]], dom: list[int], incumbent: int, sol, target: int, nodes: int,
            order: list[np.ndarray] = f.order, nconf=f.nconf, tw: np.ndarray = f.target_coarse):
        """DFS from the root over the tables ``order`` / ``nconf`` (``W`` in the same
        order); returns (completed, best, sol).  ``target >= 0``: stop at the first
        solution of weight >= target (feasibility mode)."""
        state.update(best=incumbent, sol=sol, limit=state["nodes"] + nodes)
        # the best distinct available targets (weight, target): the i-th largest value of
        # any solution is <= the i-th largest best-in-domain of the free arms AND <= the
        # i-th largest weight of a distinct target not yet taken (matching bound, O(m))
        av = np.flatnonzero(problem.available)
        top_i = av[np.argsort(-tw[av], kind="stable")[:2 * n_arms]]
        TOP = [(int(tw[t]), int(t)) for t in top_i]
        def capped(cur: int, bl: list[int], taken: list[int]) -> int:
            bl.sort(reverse=True)
            tot = cur
            i = 0
            n = len(bl)
            for wt, t in TOP:
                if i == n:
                    break
                if t in taken:
                    continue
                b = bl[i]
                tot += b if b < wt else wt
                i += 1
            return tot

        def dfs(dom: list[int], free: list[int], cur: int, bests: dict, pick: list) -> None:
            state["nodes"] += 1
            if state["nodes"] > state["limit"]:
                raise _Limit
            if not state["nodes"] & 1023:
                settle()
                if budget is not None and budget.expired():
                    raise _Limit
            if not free:
                if target >= 0:
                    state["best"], state["sol"] = cur, list(pick)
                    raise _Found
                if cur > state["best"]:
                    state["best"], state["sol"] = cur, list(pick)
                return
            sizes = [dom[j].bit_count() for j in free]
            k = free[sizes.index(min(sizes))]  # fail first (the first of the smallest domains)
            others = [j for j in free if j != k]
            rest = cur + sum([bests[j] for j in others])
            thr = state["best"] if target < 0 else target - 1
            d = dom[k]
            Wk = W[k]
            ok = order[k]
            taken0 = [tgt_of[p] for p in pick if p >= 0]  # the node's targets (arm k is free)
            while d:
                low = d & -d
                i = low.bit_length() - 1
                d ^= low
                wv = Wk[i]
                if rest + wv <= thr:
                    break  # values are in weight order: nothing later can do better
                aidx = int(ok[i])
                nc = nconf[aidx]
                nd = dom[:]
                nb = {}
                tot = cur + wv
                for j in others:
                    x = dom[j] & nc[j]
                    if not x:
                        break
                    nd[j] = x
                    bj = W[j][(x & -x).bit_length() - 1]
                    nb[j] = bj
                    tot += bj
                else:
                    if tot > thr:
                        pick[k] = aidx
                        if capped(cur + wv, list(nb.values()), taken0 + [tgt_of[aidx]]) > thr:
                            dfs(nd, others, cur + wv, nb, pick)
                        pick[k] = -1
                        thr = state["best"] if target < 0 else target - 1

        bests = {k: W[k][(dom[k] & -dom[k]).bit_length() - 1] for k in range(n_arms)}
        try:
            dfs(dom, list(range(n_arms)), 0, bests, [-1] * n_arms)
        except _Limit:
            return False, state["best"], state["sol"]
        except _Found:
            return True, state["best"], state["sol"]
        finally:
            settle()
        return True, state["best"], state["sol"]

    def full_w(ch) -> int:
        return int(sum(int(w_all[c]) for c in ch))

    def coarse_w(ch) -> int:
        return sum(f.coarse[k][int(f.pos[ch[k]])] for k in range(n_arms))

    inc_c, sol = -1, None
    if hint is not None:
        hint = np.asarray(hint, int)
        if consistent(hint, f, dom0):
            inc_c, sol = coarse_w(hint), [int(v) for v in hint]
    root_c = sum(f.coarse[k][(dom0[k] & -dom0[k]).bit_length() - 1] for k in range(n_arms))
    out["bound"] = root_c * tie_mult + n_arms * max_tie
    # stage 1: coarse weight (priority, yield); or proven elsewhere (CP-SAT)
    if coarse_optimum is not None:
        inc_c, sol = int(coarse_optimum[0]), [int(v) for v in coarse_optimum[1]]
        done = True
    elif inc_c < root_c:
        done, inc_c, sol = run(f.coarse, dom0, inc_c, sol, -1, node_limit)
    else:
        done = True
    out.update(proved=done, nodes=state["nodes"])
    if sol is None:
        out.update(tie_proved=done, move_proved=done)
        return out
    sol = np.array(sol, np.int64)
    w_c = inc_c

    def subtable(cols_allowed: np.ndarray) -> _TieTables:
        """Tables over the columns that can still reach coarse weight ``w_c`` (exact
        probing, one pass: a superset is enough) plus the incumbent's, in full-weight order."""
        cols = prune_columns(problem, w_c, f, max_passes=1, allowed=cols_allowed)
        cols[sol] = True
        return _tie_tables(problem, cols, w_all)
    out.update(chosen=sol, weight=full_w(sol))
    if not done:
        # stage 1 hit its limit (a tier transition): one more search over the columns that
        # can reach the incumbent, in full-weight order — any solution it finds beats the
        # incumbent in priority/yield or, equal there, in the tie-break
        if tie_mult > 1 and tie_node_limit > 0:
            tt = subtable(allowed)
            keep = [(1 << len(o)) - 1 for o in tt.order]
            _, w3, s3 = run(tt.weights, keep, full_w(sol), [int(v) for v in sol], -1, tie_node_limit,
                            order=tt.order, nconf=tt.nconf, tw=tt.target_full)
            out.update(chosen=np.array(s3, np.int64), weight=w3)
        out.update(tie_proved=False, move_proved=False, nodes=state["nodes"])
        return out
    # stages 2 and 3 run on a small table of the columns that can still reach the coarse
    # optimum (exact probing, one pass: a superset is enough) within the current longest
    # move, ordered by the full weight of THIS problem (its tie-break changes every
    # configuration): the first dives then favour the tie-break, as stage 3 asks
    mv_best = float(move[sol].max())
    tab_order, tab_nconf, tab_tw, tab_coarse = f.order, f.nconf, f.target_coarse, f.coarse
    tt = None
    if tie_mult > 1 or minimize_move:
        lim = mv_best if minimize_move else np.inf
        tt = subtable(allowed & (move <= lim))
        tab_order, tab_nconf, tab_tw = tt.order, tt.nconf, tt.target_full // tie_mult
        tab_coarse = [[v // tie_mult for v in wk] for wk in tt.weights]
    tab = dict(order=tab_order, nconf=tab_nconf, tw=tab_tw)
    # stage 2 (eq. 5.16): same coarse weight, strictly shorter longest move; restart after
    # each improvement (the coarse bound is tight, so these searches are short)
    move_proved = True
    if minimize_move:
        budget_end = state["nodes"] + move_node_limit
        while True:
            keep = [_mask(move[tab_order[k]] < mv_best) for k in range(n_arms)]
            if any(d == 0 for d in keep):
                break
            if sum(tab_coarse[k][(keep[k] & -keep[k]).bit_length() - 1] for k in range(n_arms)) < w_c:
                break
            left = budget_end - state["nodes"]
            if left <= 0:
                move_proved = False
                break
            done2, _, s2 = run(tab_coarse, keep, -1, None, w_c, left, **tab)
            if not done2:
                move_proved = False
                break
            if s2 is None:
                break
            sol = np.array(s2, np.int64)
            mv_best = float(move[sol].max())
    else:
        move_proved = False
    # stage 3: the tie-break, among solutions of that coarse weight and longest move
    w_full = full_w(sol)
    tie_proved = True
    if tie_mult > 1:
        lim = mv_best if minimize_move else np.inf
        keep = [_mask(move[o] <= lim) for o in tt.order]
        tie_proved, w_full, s3 = run(tt.weights, keep, w_full, [int(v) for v in sol], -1, tie_node_limit,
                                     order=tt.order, nconf=tt.nconf, tw=tt.target_full)
        sol = np.array(s3, np.int64)
    out.update(chosen=sol, weight=w_full, move_proved=move_proved, tie_proved=tie_proved, nodes=state["nodes"])
    return out


def prune_columns(problem: ConfigProblem, incumbent_coarse: int, field: BnbField | None = None,
                  max_passes: int = 4, allowed: np.ndarray | None = None) -> np.ndarray:
    """Exact column fixing for the coarse (priority, yield) objective: drop every allowed
    assignment ``a`` of arm ``k`` whose *probing bound* ``w(a) + sum_{j != k} max{w(b) : b in
    dom_j, b compatible with a}`` is strictly below ``incumbent_coarse``; repeated on the
    reduced domains until nothing changes (at most ``max_passes``).

    No solution of coarse weight >= the incumbent uses a dropped column (its weight is at
    most that bound), so a model restricted to the kept columns has the same optimum AND the
    same set of optimal solutions (the longest-move stage stays exact).  Returns the
    (n_assignments,) bool mask of kept columns (rest locations are kept regardless).
    ``allowed`` narrows the problem's allowed columns (e.g. to a move limit).
    """
    f = field or prepare_field(problem)
    allowed = problem.allowed() if allowed is None else allowed
    n_arms = f.n_arms
    W = f.coarse
    dom = [_mask(allowed[f.order[k]]) for k in range(n_arms)]
    if any(d == 0 for d in dom):
        return allowed.copy()
    probes = 0
    for _ in range(max_passes):
        changed = False
        for k in range(n_arms):
            bests = [W[j][(dom[j] & -dom[j]).bit_length() - 1] for j in range(n_arms)]
            others = [j for j in range(n_arms) if j != k]
            rest_max = sum(bests[j] for j in others)
            d = dom[k]
            keep = 0
            ok = f.order[k]
            Wk = W[k]
            while d:
                low = d & -d
                i = low.bit_length() - 1
                d ^= low
                wv = Wk[i]
                if wv + rest_max < incumbent_coarse:
                    break  # weight order: every later value is pruned as well
                nc = f.nconf[int(ok[i])]
                probes += 1
                tot = wv
                for j in others:
                    x = dom[j] & nc[j]
                    if not x:
                        tot = -1
                        break
                    tot += W[j][(x & -x).bit_length() - 1]
                if tot >= incumbent_coarse:
                    keep |= low
            if keep != dom[k]:
                changed = True
                dom[k] = keep
                if not keep:
                    clock.charge(probes * PRUNE_PROBE_S)
                    return np.zeros(len(allowed), bool)
        if not changed:
            break
    clock.charge(probes * PRUNE_PROBE_S)
    out = np.zeros(len(allowed), bool)
    for k in range(n_arms):
        bits = np.unpackbits(np.frombuffer(dom[k].to_bytes((len(f.order[k]) + 7) // 8, "little"), np.uint8),
                             bitorder="little")[:len(f.order[k])].astype(bool)
        out[f.order[k][bits]] = True
    return out | (allowed & (problem.assignments.target < 0))


def consistent(chosen: np.ndarray, f: BnbField, dom: list[int]) -> bool:
    if chosen.shape != (f.n_arms,) or (chosen < 0).any():
        return False
    for k in range(f.n_arms):
        b = int(f.pos[chosen[k]])
        if not (dom[k] >> b) & 1 or int(f.order[k][b]) != int(chosen[k]):
            return False
        for j in range(k + 1, f.n_arms):
            if not (f.nconf[int(chosen[k])][j] >> int(f.pos[chosen[j]])) & 1:
                return False
    return True
