"""Field segmentation (solvers.segmentation) -- issue 3 tests."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import pdist

from models.errors import InputError
from models.sky import focal_mm_to_sky, sky_to_focal_mm
from solvers.segmentation import (
    Segmentation,
    segment_field,
    threshold_complete_linkage,
)
from solvers.segmentation.enclosing_circle import smallest_enclosing_circle

R = 125.0
SCALE = 1.2


def partition(labels) -> set[frozenset[int]]:
    out: dict[int, set[int]] = {}
    for i, lab in enumerate(np.asarray(labels).tolist()):
        out.setdefault(lab, set()).add(i)
    return {frozenset(s) for s in out.values()}


def scipy_partition(points, t):
    if len(points) == 1:
        return {frozenset([0])}
    return partition(fcluster(linkage(points, "complete"), t, "distance"))


def random_points(seed, n, density_per_threshold2):
    """n uniform points; the square side makes about `density` points per threshold^2."""
    rng = np.random.default_rng(seed)
    side = 100.0 * math.sqrt(n / density_per_threshold2)
    pts = rng.uniform(0, side, (n, 2))
    if rng.uniform() < 0.5:  # clumpy variant: half the points in a few Gaussian clumps
        k = n // 2
        centres = rng.uniform(0, side, (5, 2))
        pts[:k] = centres[rng.integers(0, 5, k)] + rng.normal(0, 40, (k, 2))
    return pts


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 600), density=st.floats(0.05, 20.0))
def test_sparse_and_nn_chain_equal_scipy_complete_linkage(seed, n, density):
    pts = random_points(seed, n, density)
    expected = scipy_partition(pts, 100.0)
    assert partition(threshold_complete_linkage(pts, 100.0, method="sparse")) == expected
    if n <= 300:
        assert partition(threshold_complete_linkage(pts, 100.0, method="nn-chain")) == expected


@pytest.mark.parametrize("seed, density", [(1, 0.5), (2, 5.0), (3, 40.0)])
def test_2000_points_equal_scipy(seed, density):
    pts = random_points(seed, 2000, density)
    assert len(np.unique(pdist(pts))) == len(pdist(pts))  # no distance ties
    expected = scipy_partition(pts, 100.0)
    assert partition(threshold_complete_linkage(pts, 100.0, method="sparse")) == expected
    assert partition(threshold_complete_linkage(pts, 100.0, method="auto")) == expected


def test_nn_chain_2000_points_equal_scipy():
    pts = random_points(4, 2000, 3.0)
    assert partition(threshold_complete_linkage(pts, 100.0, method="nn-chain")) == \
        scipy_partition(pts, 100.0)


def test_thesis_synthetic_20_points_in_50mm_square():
    pts = np.random.default_rng(2019).uniform(0, 50, (20, 2))
    labels = threshold_complete_linkage(pts, 25.0, method="nn-chain")
    d = np.hypot(*(pts[:, None] - pts[None]).transpose(2, 0, 1))
    for a in np.unique(labels):
        ia = labels == a
        assert d[np.ix_(ia, ia)].max() <= 25.0  # intra-cluster diameter within threshold
        for b in np.unique(labels):
            if b != a:  # inter-cluster (complete-linkage) distance beyond it (thesis tab. 4.1)
                assert d[np.ix_(ia, labels == b)].max() > 25.0


# ---------------------------------------------------------------- smallest enclosing circle


def assert_circle_matches_shapely(pts):
    cx, cy, r = smallest_enclosing_circle(pts)
    mp = shapely.multipoints(pts)
    assert r == pytest.approx(shapely.minimum_bounding_radius(mp), abs=1e-6)
    if r > 0:
        c = shapely.minimum_bounding_circle(mp).centroid
        assert math.hypot(cx - c.x, cy - c.y) <= 1e-6
    assert np.all(np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) <= r + 1e-9)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), spread=st.floats(1e-3, 1e4))
def test_enclosing_circle_equals_shapely(seed, n, spread):
    rng = np.random.default_rng(seed)
    assert_circle_matches_shapely(rng.normal(size=(n, 2)) * spread + rng.uniform(-1e4, 1e4, 2))


@pytest.mark.parametrize(
    "pts",
    [
        [[3.0, 4.0]],
        [[0.0, 0.0], [10.0, 0.0]],
        [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 5.0], [3.0, 3.0]],  # collinear
        [[1.0, 1.0], [1.0, 1.0], [4.0, 5.0], [4.0, 5.0], [1.0, 1.0]],  # duplicates
        [[7.0, -2.0]] * 6,  # all identical
        [[0.0, 0.0], [2.0, 0.0], [1.0, math.sqrt(3.0)]],  # equilateral: circumcircle
        [[math.cos(a), math.sin(a)] for a in np.linspace(0, 2 * math.pi, 200, endpoint=False)],
    ],
)
def test_enclosing_circle_degenerate_sets(pts):
    assert_circle_matches_shapely(np.array(pts, dtype=float))


def test_enclosing_circle_large_set_uses_vectorised_path():
    assert_circle_matches_shapely(np.random.default_rng(5).uniform(-300, 300, (5000, 2)))


# ------------------------------------------------------------------------ segment_field


def scatter(seed, ra0, dec0, n, radius_deg):
    rng = np.random.default_rng(seed)
    r_mm = radius_deg * 3600 / SCALE * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * math.pi, n)
    return focal_mm_to_sky(r_mm * np.cos(a), r_mm * np.sin(a), ra0, dec0, SCALE)


def check_guarantees(seg: Segmentation, ra, dec):
    seen = np.zeros(len(ra), dtype=int)
    for p in seg.pointings:
        idx = np.array(p.target_indices)
        seen[idx] += 1
        # independent check: project the members on a plane about THIS pointing's centre
        x, y = sky_to_focal_mm(ra[idx], dec[idx], p.ra_deg, p.dec_deg, SCALE)
        r = np.hypot(x, y)
        assert r.max() <= R + 1e-6, (p.id, r.max())
        assert p.radius_mm == pytest.approx(r.max(), abs=1e-6)
        assert 0.0 <= p.ra_deg < 360.0 and -90.0 <= p.dec_deg <= 90.0
    assert np.all(seen == 1)
    assert seg.stats["n_pointings"] == len(seg.pointings)


@pytest.mark.parametrize("mode", ["complete-linkage", "balanced"])
@pytest.mark.parametrize(
    "ra0, dec0, radius_deg, n",
    [
        (0.0, 0.0, 0.1, 1500),  # straddles RA = 0/360
        (359.99, 30.0, 0.05, 800),
        (120.0, 89.9, 0.15, 1500),  # around the north celestial pole
        (10.0, -89.95, 0.1, 800),
        (200.0, 20.0, 5.0, 3000),  # 10 deg wide field
    ],
)
def test_every_member_inside_its_own_fov(mode, ra0, dec0, radius_deg, n):
    ra, dec = scatter(hash((ra0, dec0)) % 1000, ra0, dec0, n, radius_deg)
    seg = segment_field(ra, dec, mode=mode)
    check_guarantees(seg, ra, dec)


def test_ra_wrap_field_is_one_pointing():
    ra = np.array([359.99, 359.995, 0.0, 0.005, 0.01])
    dec = np.zeros(5)
    seg = segment_field(ra, dec)
    assert len(seg.pointings) == 1
    check_guarantees(seg, ra, dec)
    p = seg.pointings[0]
    assert min(p.ra_deg, 360.0 - p.ra_deg) < 0.001


def test_clusters_that_do_not_fit_are_repaired_not_returned():
    """Threshold 2R allows clusters that do not fit: the repair step must split them."""
    ra, dec = scatter(11, 200.0, 40.0, 2000, 1.0)
    seg = segment_field(ra, dec, threshold_mm=2 * R)
    check_guarantees(seg, ra, dec)
    assert seg.stats["n_repaired_clusters"] > 0


def test_equilateral_triangle_wider_than_fov_is_split():
    side = 240.0  # circumradius 138.6 mm > R, all sides <= threshold 250 mm
    x = np.array([0.0, side, side / 2])
    y = np.array([0.0, 0.0, side * math.sqrt(3) / 2])
    ra, dec = focal_mm_to_sky(x, y, 50.0, 10.0, SCALE)
    seg = segment_field(ra, dec, threshold_mm=250.0)
    assert len(seg.pointings) == 2
    check_guarantees(seg, ra, dec)
    default = segment_field(ra, dec)  # sqrt(3) R = 216.5 < 240: three separate clusters
    assert len(default.pointings) == 3


def test_balanced_mode_not_worse_than_complete_linkage():
    ra, dec = scatter(3, 150.0, 10.0, 3000, 0.35)
    cl = segment_field(ra, dec)
    bal = segment_field(ra, dec, mode="balanced")
    check_guarantees(bal, ra, dec)
    assert bal.stats["n_pointings"] < cl.stats["n_pointings"]
    assert bal.stats["members_std"] < cl.stats["members_std"]


def test_same_seed_same_answer():
    ra, dec = scatter(9, 30.0, -30.0, 500, 0.2)
    assert segment_field(ra, dec, mode="balanced").pointings == \
        segment_field(ra, dec, mode="balanced").pointings


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(ra_deg=[1.0, float("nan")], dec_deg=[0.0, 0.0]), "targets[1].ra_deg"),
        (dict(ra_deg=[1.0, 360.0], dec_deg=[0.0, 0.0]), "targets[1].ra_deg"),
        (dict(ra_deg=[-1.0, 1.0], dec_deg=[0.0, 0.0]), "targets[0].ra_deg"),
        (dict(ra_deg=[1.0, 1.0], dec_deg=[0.0, -90.5]), "targets[1].dec_deg"),
        (dict(ra_deg=[1.0, 1.0], dec_deg=[float("inf"), 0.0]), "targets[0].dec_deg"),
        (dict(ra_deg=[], dec_deg=[]), "targets"),
        (dict(threshold_mm=0.0), "threshold_mm"),
        (dict(threshold_mm=-5.0), "threshold_mm"),
        (dict(threshold_mm=float("nan")), "threshold_mm"),
        (dict(threshold_mm=250.1), "threshold_mm"),
        (dict(fov_radius_mm=0.0), "fov_radius_mm"),
        (dict(plate_scale_arcsec_per_mm=-1.2), "plate_scale_arcsec_per_mm"),
        (dict(mode="fastest"), "mode"),
        (dict(tangent_point=(10.0, 95.0)), "tangent_point.dec_deg"),
        (dict(ra_deg=[1.0, 181.0], dec_deg=[0.0, 0.0], tangent_point=(1.0, 0.0)),
         "targets[1].dec_deg"),
    ],
)
def test_bad_input_names_the_field(kwargs, field):
    args = dict(ra_deg=[1.0, 1.01], dec_deg=[0.0, 0.0])
    args.update(kwargs)
    ra, dec = args.pop("ra_deg"), args.pop("dec_deg")
    with pytest.raises(InputError) as e:
        segment_field(ra, dec, **args)
    assert e.value.field == field
