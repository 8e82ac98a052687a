"""The arithmetic of models.budget.Budget on a fake clock, and a budget inside clock.effort()
counting charged work rather than wall time."""

from __future__ import annotations

import dataclasses
import math
import time

import pytest

from models import clock
from models.budget import Budget


class FakeNow:
    """A stand-in for models.clock.now: it moves only when the test advances it, and counts
    its readings."""

    def __init__(self, t_s: float = 100.0) -> None:
        self.t_s = t_s
        self.reads = 0

    def now(self) -> float:
        self.reads += 1
        return self.t_s


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch) -> FakeNow:
    c = FakeNow()
    monkeypatch.setattr(clock, "now", c.now)
    return c


def test_start_counts_from_now(fake: FakeNow) -> None:
    b = Budget.start(10.0)
    assert (b.start_s, b.deadline_s, b.total_s, b.hard_deadline_s) == (100.0, 110.0, 10.0, 110.0)
    assert b.limit_s == 10.0 and not b.unlimited
    fake.t_s = 104.0
    assert b.left_s() == 6.0 and b.elapsed_s() == 4.0 and not b.expired()
    fake.t_s = 110.0
    assert b.left_s() == 0.0 and not b.expired()  # expired only past the deadline
    fake.t_s = 111.5
    assert b.left_s() == -1.5 and b.expired()


def test_share_is_a_fraction_of_the_total_from_now(fake: FakeNow) -> None:
    b = Budget.start(10.0)
    fake.t_s = 102.0
    s = b.share(0.3)
    assert (s.start_s, s.deadline_s) == (102.0, pytest.approx(105.0))
    assert s.total_s == 10.0 and s.hard_deadline_s == 110.0  # the whole's, for the next share
    assert b.share(0.3, cap_s=1.0).deadline_s == 103.0  # the cap binds
    # a share of a share is still a fraction of the whole budget, within the share
    fake.t_s = 104.0
    assert s.share(0.05).deadline_s == pytest.approx(104.5)
    assert s.share(0.5).deadline_s == s.deadline_s


def test_share_never_passes_the_deadline(fake: FakeNow) -> None:
    b = Budget.start(10.0)
    fake.t_s = 108.0
    s = b.share(0.8, cap_s=5.0)  # 5 s from now would end at 113
    assert s.deadline_s == b.deadline_s == 110.0
    assert s.left_s() == 2.0
    fake.t_s = 120.0  # the budget has passed: a share of it has too
    late = b.share(0.5)
    assert late.deadline_s == 110.0 and late.expired() and late.left_s() == -10.0


def test_keep_holds_seconds_back_at_the_end(fake: FakeNow) -> None:
    b = Budget.start(10.0)
    reads = fake.reads
    k = b.keep(2.5)
    assert fake.reads == reads  # nothing to read: the same start
    assert (k.start_s, k.deadline_s, k.total_s, k.hard_deadline_s) == (100.0, 107.5, 10.0, 110.0)
    fake.t_s = 103.0
    assert k.share(0.9).deadline_s == 107.5  # a share of what is left after the keep-back
    fake.t_s = 108.0
    assert k.expired() and not b.expired()


def test_child_is_a_budget_of_its_own_within_the_parent(fake: FakeNow) -> None:
    b = Budget.start(10.0)
    fake.t_s = 103.0
    c = b.child(4.0)
    assert (c.start_s, c.deadline_s, c.total_s, c.hard_deadline_s) == (103.0, 107.0, 4.0, 107.0)
    assert c.share(0.5).deadline_s == 105.0  # a fraction of its own length
    fake.t_s = 108.0
    late = b.child(5.0)  # past the parent's deadline: cut to it
    assert late.deadline_s == 110.0 and late.total_s == 2.0 and late.limit_s == 2.0


@pytest.mark.parametrize("limit_s", [None, math.inf])
def test_unlimited_budget(fake: FakeNow, limit_s: float | None) -> None:
    b = Budget.start(limit_s)
    assert b.unlimited and b.start_s == 100.0
    assert b.deadline_s == b.total_s == b.hard_deadline_s == b.limit_s == math.inf
    reads = fake.reads
    fake.t_s = 1e12
    assert b.left_s() == math.inf and not b.expired()
    assert fake.reads == reads  # nothing to compare: the clock is not read
    assert b.elapsed_s() == 1e12 - 100.0
    assert b.share(0.5).unlimited  # half of no limit
    capped = b.share(0.5, cap_s=3.0)
    assert capped.deadline_s == 1e12 + 3.0 and capped.hard_deadline_s == math.inf
    c = b.child(7.0)
    assert (c.deadline_s, c.total_s) == (1e12 + 7.0, 7.0)


def test_fields_are_floats_and_frozen(fake: FakeNow) -> None:
    b = Budget(start_s=0, deadline_s=20, total_s=20)
    assert all(type(v) is float for v in dataclasses.astuple(b))
    assert b.hard_deadline_s == 20.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.deadline_s = 30.0  # type: ignore[misc]


def test_inside_effort_a_budget_counts_charged_work_not_wall_time() -> None:
    with clock.effort():
        b = Budget.start(1.0)
        time.sleep(0.05)  # wall time passes, no work is charged
        assert not b.expired()
        assert b.elapsed_s() < 10 * clock.TICK_S  # only the readings' ticks
        clock.charge(0.6)
        assert b.left_s() == pytest.approx(0.4, abs=10 * clock.TICK_S)
        s = b.share(0.25)
        clock.charge(0.3)
        assert s.expired() and not b.expired()
        clock.charge(0.2)
        assert b.expired()


def test_outside_effort_a_budget_counts_wall_time() -> None:
    b = Budget.start(0.02)
    clock.charge(10.0)  # no effort clock: charging does nothing
    assert not b.expired()
    time.sleep(0.03)
    assert b.expired() and b.elapsed_s() >= 0.03


def test_ending_at_an_instant_reads_no_clock(fake: FakeNow) -> None:
    b = Budget.ending_at(107.0)
    assert fake.reads == 0 and b.deadline_s == 107.0 and not b.unlimited
    assert b.left_s() == 7.0 and not b.expired()
    fake.t_s = 103.0
    assert b.share(0.5).deadline_s == 107.0  # no known total: a share is all that is left
    assert b.child(2.0).deadline_s == 105.0
    assert Budget.ending_at(None).unlimited and Budget.ending_at(math.inf).unlimited


def test_past_deadline_reads_the_clock_even_when_unlimited(fake: FakeNow) -> None:
    u = Budget.start(None)
    fake.reads = 0
    assert not u.expired() and fake.reads == 0
    assert not u.past_deadline() and fake.reads == 1
    b = Budget.start(5.0)
    fake.t_s = 105.0
    assert not b.past_deadline()
    fake.t_s = 105.5
    assert b.past_deadline() and b.expired()


def test_part_is_counted_from_the_start_without_reading_the_clock(fake: FakeNow) -> None:
    b = Budget.start(10.0)
    fake.t_s = 104.0
    fake.reads = 0
    p = b.part(0.3)
    assert fake.reads == 0
    assert (p.start_s, p.deadline_s, p.total_s, p.hard_deadline_s) == (100.0, 100.0 + 0.3 * 10.0, 10.0, 110.0)
    assert b.part(1.0).deadline_s == b.deadline_s and b.part(2.0).deadline_s == b.deadline_s
    assert p.expired() and b.part(0.3).left_s() == pytest.approx(-1.0)
