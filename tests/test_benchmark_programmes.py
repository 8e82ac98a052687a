"""benchmarks/programmes.py: its programmes have the shapes it names, and its smoke run goes
through the POST /v1/plans call and reports what the README's row quotes."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import programmes  # noqa: E402


@pytest.mark.parametrize("shape", programmes.SHAPES)
def test_programmes_are_deterministic_and_in_the_thesis_mix(shape: str) -> None:
    a, pa = programmes.programme_targets(shape, 7)
    b, pb = programmes.programme_targets(shape, 7)
    assert a == b and pa == pb and 40 <= len(a) <= 200
    prio = np.array([t["priority"] for t in a])
    assert set(prio) <= {500, 100, 10, 1}
    assert programmes.programme_targets(shape, 8)[0] != a


def test_a_cluster_is_concentrated_and_a_scattered_field_is_not() -> None:
    def spread_arcmin(targets):
        ra = np.array([t["ra_deg"] for t in targets])
        dec = np.array([t["dec_deg"] for t in targets])
        x = (ra - np.median(ra)) * np.cos(np.radians(dec)) * 60
        y = (dec - np.median(dec)) * 60
        return float(np.median(np.hypot(x, y)))

    clusters = [spread_arcmin(programmes.programme_targets("cluster", s)[0]) for s in range(5)]
    scattered = [spread_arcmin(programmes.programme_targets("scattered", s)[0]) for s in range(5)]
    assert max(clusters) < min(scattered)


def test_the_smoke_run_reports_every_programme() -> None:
    out = programmes.main(["--smoke"])
    assert out["programmes"] == 2 and len(out["rows"]) == 2
    for row in out["rows"]:
        assert row["limit_s"] == 120.0 and row["legs"] >= row["legs_planned"] > 0
        assert row["executable"] == (row["legs"] == row["legs_planned"])
        assert 0 < row["time_used"] <= 1.0
    assert out["executable"] == sum(r["executable"] for r in out["rows"])
