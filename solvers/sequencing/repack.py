"""Repacking a finished sequence into fewer configurations (beyond the thesis).

Three strategies over one multi-configuration model (:func:`solvers.sequencing.packing.pack_targets`:
each pooled target exactly once, per-configuration eqs. 5.13–5.15): the under-filled tail
into the b-matching bound (:func:`repack_bulk`); bottom-up the longest suffix of at most
``bottom_pool`` targets into as few configurations as bisection finds, keeping the longest
prefix of maximum-priority configurations (:func:`pack_fewest`); then one configuration
fewer at a time (:func:`repack_prefix`).  Their constants are those of
:class:`solvers.sequencing.shares.SequenceShares`.
"""

from __future__ import annotations

import math

import numpy as np

from models import clock
from solvers.sequencing.bounds import matching_lower_bound
from solvers.sequencing.packing import pack_targets
from solvers.sequencing.shares import SHARES
from solvers.sequencing.state import active_arms, observed_chosen, replace_tail

__all__ = ["pack_fewest", "repack_bulk", "repack_prefix"]


def repack_bulk(instrument, inc, priority, configs, lower_bound, speeds, xy, tie, budget_s, seed, threads):
    """Re-pack the whole under-filled tail at once.

    One-at-a-time sequencing leaves the hard-to-place targets (few arms reach them) for
    the end, where they fill configurations one or two at a time.  The tail is the longest
    suffix whose configurations are not all full (plus the one before it); its targets are
    packed by :func:`pack_targets` into as few configurations as the b-matching bound
    (:func:`matching_lower_bound`) allows, then one more at a time while it fails.
    """
    t0 = clock.now()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    yields = [int((a.target[ch] >= 0).sum()) for _, ch, _, _ in configs]
    full = max(yields, default=0)
    w = 0
    while w < len(configs) and yields[len(configs) - 1 - w] < full:
        w += 1
    window = min(w + 1, len(configs))
    if w < 2:
        return configs
    tail = configs[-window:]
    pool = np.concatenate([observed_chosen(inc, ch) for _, ch, _, _ in tail])
    mask = np.zeros(inc.reachability.n_targets, bool)
    mask[pool] = True
    need = max(matching_lower_bound(inc, mask), math.ceil(len(pool) / max(n_arms, 1)),
               lower_bound - (len(configs) - window))
    c = need
    while c < window:
        left = budget_s - (clock.now() - t0)
        if left <= SHARES.min_search_s:
            break
        ts = clock.now()
        packed = pack_targets(inc, pool, c, time_limit_s=min(left, max(left / max(window - c, 1), SHARES.min_search_s)),
                              seed=seed + SHARES.bulk_seed_offset + c, threads=threads, hint=[ch for _, ch, _, _ in tail])
        if packed is not None:
            return replace_tail(instrument, inc, priority, configs, window, packed, speeds, xy, tie,
                                 clock.now() - ts)
        c += 1
    return configs


def pack_fewest(instrument, inc, priority, configs, extra, lower_bound, speeds, xy, tie, attempt_s,
                 refine_s, budget_s, seed, threads, max_pool, q0):
    """Bottom-up repacking: the longest suffix of at most ``max_pool`` targets (plus the
    rescued ``extra`` ones) is packed into as few configurations as possible, trying
    lower_bound, lower_bound + 1, ... and stopping at the first success; then the longest
    prefix of the original configurations that still allows that count is searched by
    bisection (feasibility is monotone in the prefix length).  Returns None when nothing was
    tried, else (configurations, proven lower bound, packed?)."""
    t0 = clock.now()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    n_active = len(active_arms(inc, n_arms))
    n_main = len(configs)
    per = [observed_chosen(inc, ch) for _, ch, _, _ in configs] + list(extra)
    n = len(per)
    sizes = np.array([len(t) for t in per])
    suffix = np.cumsum(sizes[::-1])[::-1]
    ok = np.flatnonzero(suffix[:n_main] <= max_pool)
    if not len(ok) or n <= lower_bound:
        return None
    h0 = int(ok.min())
    proven = lower_bound

    n_attempts = [0]

    def attempt(h: int, count: int, limit: float):
        pool = np.concatenate(per[h:])
        st: dict = {}
        # a seed per attempt: the same pool, count and hint with the same seed would repeat
        # the earlier tabu search step for step
        n_attempts[0] += 1
        packed = pack_targets(inc, pool, count - h, time_limit_s=limit, seed=seed + SHARES.attempt_seed_stride * n_attempts[0],
                              threads=threads,
                              hint=[ch for _, ch, _, _ in configs[h:]], status_out=st)
        return packed, pool, st["infeasible"]

    best = None
    # bisection on the count (a time-out counts as a failure, so the result is the fewest
    # configurations found, not necessarily the fewest that exist)
    lo, hi = max(lower_bound, h0 + math.ceil(suffix[h0] / n_arms)), n - 1
    while lo <= hi:
        left = budget_s - (clock.now() - t0)
        if left <= SHARES.min_search_s:
            break
        count = (lo + hi) // 2
        ts = clock.now()
        # the attempts the bisection still needs share what is left (at least attempt_s each)
        share = left / max(1, math.ceil(math.log2(hi - lo + 2)))
        packed, pool, infeasible = attempt(h0, count, min(left, max(attempt_s, share)))
        if packed is not None:
            best = (h0, count, packed, pool, clock.now() - ts)
            hi = count - 1
        else:
            lo = count + 1
            # with rescued targets in the pool the model (park rests only) is stricter than
            # the rescue, which may rest idle arms on blank sky — unless the pool fills every
            # active arm of every configuration, when no arm rests at all
            if infeasible and h0 == 0 and (not extra or len(pool) >= n_active * count):
                proven = max(proven, count + 1)
    if best is None:
        return configs, proven, False
    h_lo, count = best[0], best[1]
    fits = np.flatnonzero(suffix[:n_main] <= n_arms * (count - np.arange(n_main)))
    h_hi = int(fits.max()) if len(fits) else h_lo
    while h_lo < h_hi:  # keep as many maximum-priority configurations as the count allows
        left = budget_s - (clock.now() - t0)
        if left <= SHARES.min_search_s:
            break
        mid = (h_lo + h_hi + 1) // 2
        ts = clock.now()
        packed, pool, _ = attempt(mid, count, min(left, refine_s))
        if packed is not None:
            best, h_lo = (mid, count, packed, pool, clock.now() - ts), mid
        else:
            h_hi = mid - 1
    h, count, packed, pool, dt = best
    return replace_tail(instrument, inc, priority, configs, n_main - h, packed, speeds, xy, tie, dt,
                         q0), proven, True


def repack_prefix(instrument, inc, priority, configs, lower_bound, speeds, xy, tie, attempt_s, budget_s,
                   seed, threads, max_pool: int = SHARES.prefix_max_pool, q0=None,
                  bottom_pool: int = SHARES.bottom_pool,
                   rescued: list[np.ndarray] | None = None) -> tuple[list, int, bool]:
    """One configuration fewer at a time, keeping the longest possible prefix of
    one-at-a-time (maximum-priority, thesis 5.5) configurations.

    To go from n to n - 1 configurations, the suffix starting at configuration h is re-packed
    by :func:`pack_targets` into n - 1 - h configurations, for h = the largest index whose
    suffix fits 12 (n - 1 - h) targets, then h - 1, ... 0: feasibility is monotone in h
    (a packing of a suffix plus the configuration before it is a packing of the longer
    suffix), so the first success keeps the longest prefix.  Repeats while it succeeds.

    ``rescued``: the targets of the rescue configurations (:func:`solvers.sequencing.rescue.rescue_conflicts`),
    which come after ``configs``; they join every pool, because in a packing where every
    arm observes a target no arm is parked, so a target on a park spot needs no rescue.
    Returns the configurations, a proven lower bound on their count (when the whole field,
    h = 0, cannot be packed into n - 1, CP-SAT proves n optimal) and whether the rescued
    targets were absorbed into ``configs`` (then the rescue configurations are void).
    """
    t0 = clock.now()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    n_active = len(active_arms(inc, n_arms))
    proven = lower_bound
    extra = list(rescued or [])
    kept = 0  # rescue configurations kept apart after their targets failed to fit any packing
    n_attempts = 0
    # bottom-up first: the fewest configurations the suffix that fits the model can reach
    for use_extra in ((True, False) if extra else (False,)):
        # at most half the budget: when the big model times out, small windows still help
        left = SHARES.fewest_fraction * budget_s - (clock.now() - t0)
        res = pack_fewest(instrument, inc, priority, configs, extra if use_extra else [],
                           max(lower_bound, proven) - (0 if use_extra else len(extra)), speeds, xy, tie,
                           SHARES.fewest_attempt_factor * attempt_s, attempt_s, left, seed, threads, bottom_pool, q0)
        if res is None:
            continue
        configs, proven_here, packed = res
        proven = max(proven, proven_here)
        if packed:  # the rescue configurations are absorbed, or kept apart
            if not use_extra:
                kept, extra = len(extra), []
            else:
                extra = []
            break
    while len(configs) + len(extra) + kept > max(lower_bound, proven):
        n_main = len(configs)
        n = n_main + len(extra)
        per = [observed_chosen(inc, ch) for _, ch, _, _ in configs] + extra
        sizes = np.array([len(t) for t in per])
        suffix = np.cumsum(sizes[::-1])[::-1]  # targets in configs[h:] and the rescued ones
        fits = np.flatnonzero(suffix[:n_main] <= n_arms * (n - 1 - np.arange(n_main)))
        if not len(fits):
            if extra:
                kept, extra = len(extra), []
                continue
            break
        found = False
        for h in range(int(fits.max()), -1, -1):
            left = budget_s - (clock.now() - t0)
            if left <= SHARES.min_search_s or suffix[h] > max_pool:
                return configs, proven, not (extra or kept)
            pool = np.concatenate(per[h:])
            st: dict = {}
            ts = clock.now()
            n_attempts += 1  # a seed per attempt, as in pack_fewest
            packed = pack_targets(inc, pool, n - 1 - h, time_limit_s=min(left, attempt_s),
                                  seed=seed + SHARES.prefix_seed_offset + SHARES.attempt_seed_stride * n_attempts, threads=threads,
                                  hint=[ch for _, ch, _, _ in configs[h:]], status_out=st)
            if packed is not None:
                configs = replace_tail(instrument, inc, priority, configs, n_main - h, packed, speeds, xy, tie,
                                        clock.now() - ts, q0)
                extra, found = [], True
                break
            if h == 0 and st["infeasible"] and (not extra or len(pool) >= n_active * (n - 1)):
                # (with rescued targets in the pool the model is stricter than the rescue,
                # which may rest idle arms on blank sky: no proof then)
                proven = max(proven, n)
        if not found:
            if extra:  # the rescued targets need blank-sky rests: pack the rest without them
                kept, extra = len(extra), []
                continue
            break
    return configs, proven, not (extra or kept)
