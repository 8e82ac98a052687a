"""Sky projection (models.sky): round trip, agreement with astropy separations, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from hypothesis import given, settings
from hypothesis import strategies as st

from models.errors import InputError
from models.sky import (
    focal_mm_to_sky,
    sky_to_focal_mm,
    spherical_centroid_deg,
    tangent_radius_mm,
    validate_sky_targets,
)

SCALE = 1.2  # arcsec/mm
MAS = 1e-3 / 3600.0  # deg


def _random_field(seed, ra0, dec0, radius_deg, n=200):
    """Targets scattered within radius_deg of (ra0, dec0), drawn with astropy offsets."""
    rng = np.random.default_rng(seed)
    centre = SkyCoord(ra0 * u.deg, dec0 * u.deg)
    pa = rng.uniform(0, 360, n) * u.deg
    sep = radius_deg * np.sqrt(rng.uniform(0, 1, n)) * u.deg
    c = centre.directional_offset_by(pa, sep)
    return c.ra.deg, c.dec.deg


@settings(max_examples=40, deadline=None)
@given(
    ra0=st.floats(0, 359.999), dec0=st.floats(-90, 90), pa=st.floats(-360, 360),
    radius=st.floats(1e-4, 5.0), seed=st.integers(0, 2**16),
)
def test_round_trip_below_one_mas(ra0, dec0, pa, radius, seed):
    ra, dec = _random_field(seed, ra0, dec0, radius)
    x, y = sky_to_focal_mm(ra, dec, ra0, dec0, SCALE, pa)
    ra2, dec2 = focal_mm_to_sky(x, y, ra0, dec0, SCALE, pa)
    assert np.all((ra2 >= 0) & (ra2 < 360))
    sep = SkyCoord(ra * u.deg, dec * u.deg).separation(SkyCoord(ra2 * u.deg, dec2 * u.deg)).deg
    assert sep.max() < MAS


@settings(max_examples=40, deadline=None)
@given(
    ra0=st.floats(0, 359.999), dec0=st.floats(-90, 90), pa=st.floats(0, 360),
    radius=st.floats(1e-4, 10.0), seed=st.integers(0, 2**16),
)
def test_focal_radius_is_tan_of_astropy_separation(ra0, dec0, pa, radius, seed):
    ra, dec = _random_field(seed, ra0, dec0, radius)
    x, y = sky_to_focal_mm(ra, dec, ra0, dec0, SCALE, pa)
    sep = SkyCoord(ra0 * u.deg, dec0 * u.deg).separation(SkyCoord(ra * u.deg, dec * u.deg)).rad
    expected = np.tan(sep) * (180 / math.pi * 3600) / SCALE
    np.testing.assert_allclose(np.hypot(x, y), expected, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(tangent_radius_mm(ra, dec, ra0, dec0, SCALE), expected,
                               rtol=1e-9, atol=1e-6)


def test_small_offsets_distance_times_scale_is_separation():
    ra, dec = _random_field(1, 123.4, -45.0, 150 / 3600)  # within the 5' FOV
    x, y = sky_to_focal_mm(ra, dec, 123.4, -45.0, SCALE)
    d_mm = np.hypot(x[:, None] - x[None], y[:, None] - y[None])
    c = SkyCoord(ra * u.deg, dec * u.deg)
    sep_arcsec = c[:, None].separation(c[None]).arcsec
    # TAN distortion over a 5' field is < 1e-6 relative
    np.testing.assert_allclose(d_mm * SCALE, sep_arcsec, rtol=2e-6, atol=1e-6)


def test_axes_and_position_angle_convention():
    d = 30 * SCALE / 3600  # 30 mm
    east_x, east_y = sky_to_focal_mm(10 + d / math.cos(math.radians(20)), 20, 10, 20, SCALE)
    north_x, north_y = sky_to_focal_mm(10, 20 + d, 10, 20, SCALE)
    assert east_x == pytest.approx(30, rel=1e-4) and abs(east_y) < 0.01
    assert north_y == pytest.approx(30, rel=1e-4) and abs(north_x) < 1e-9
    # PA = 90: the instrument +y axis points East, +x South
    ex, ey = sky_to_focal_mm(10 + d / math.cos(math.radians(20)), 20, 10, 20, SCALE, 90)
    nx, ny = sky_to_focal_mm(10, 20 + d, 10, 20, SCALE, 90)
    assert ey == pytest.approx(30, rel=1e-4) and nx == pytest.approx(-30, rel=1e-4)


def test_field_across_ra_zero():
    ra = np.array([359.99, 0.0, 0.01])
    dec = np.zeros(3)
    x, y = sky_to_focal_mm(ra, dec, 0.0, 0.0, SCALE)
    np.testing.assert_allclose(x, [-30.0, 0.0, 30.0], rtol=1e-6, atol=1e-9)
    ra2, dec2 = focal_mm_to_sky(x, y, 359.9999, 0.0, SCALE)  # other side of the wrap
    x2, y2 = sky_to_focal_mm(ra2, dec2, 359.9999, 0.0, SCALE)
    np.testing.assert_allclose(x2, x, atol=1e-6)
    ra3, _ = focal_mm_to_sky(x, y, 0.0, 0.0, SCALE)
    assert np.all((ra3 >= 0) & (ra3 < 360))
    assert spherical_centroid_deg(ra, dec)[0] == pytest.approx(0.0, abs=1e-9) or \
        spherical_centroid_deg(ra, dec)[0] == pytest.approx(360.0, abs=1e-9)


@pytest.mark.parametrize("dec0", [90.0, -90.0, 89.999, -89.95])
def test_pole_tangent_points(dec0):
    ra, dec = _random_field(7, 33.0, dec0, 0.1)
    x, y = sky_to_focal_mm(ra, dec, 33.0, dec0, SCALE, 17.0)
    assert np.all(np.isfinite(x))
    ra2, dec2 = focal_mm_to_sky(x, y, 33.0, dec0, SCALE, 17.0)
    sep = SkyCoord(ra * u.deg, dec * u.deg).separation(SkyCoord(ra2 * u.deg, dec2 * u.deg)).deg
    assert sep.max() < MAS


def test_far_side_of_sphere_is_an_error():
    with pytest.raises(InputError) as e:
        sky_to_focal_mm([10.0, 190.0], [0.0, 0.0], 10.0, 0.0, SCALE)
    assert e.value.field == "dec_deg[1]"


def test_sky_to_focal_bad_coordinates():
    with pytest.raises(InputError) as e:
        sky_to_focal_mm([1.0, np.nan], [0.0, 0.0], 0.0, 0.0, SCALE)
    assert e.value.field == "ra_deg[1]"
    with pytest.raises(InputError) as e:
        sky_to_focal_mm([1.0], [91.0], 0.0, 0.0, SCALE)
    assert e.value.field == "dec_deg[0]"
    with pytest.raises(InputError) as e:
        sky_to_focal_mm([1.0], [1.0], 0.0, 0.0, -1.0)
    assert e.value.field == "plate_scale_arcsec_per_mm"


GOOD = dict(ids=["a", "b", "c"], ra_deg=[0.0, 10.0, 359.5], dec_deg=[-90.0, 0.0, 90.0],
            priority=[1, 2**32 - 1, np.int64(5)])


def test_validate_accepts_good_targets():
    validate_sky_targets(**GOOD)


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(ids=[]), "targets"),
        (dict(ids=["a", "b", "a"]), "targets[2].id"),
        (dict(ra_deg=[0.0, float("nan"), 1.0]), "targets[1].ra_deg"),
        (dict(ra_deg=[0.0, 360.0, 1.0]), "targets[1].ra_deg"),
        (dict(ra_deg=[-0.1, 1.0, 1.0]), "targets[0].ra_deg"),
        (dict(ra_deg=[0.0, 1.0, float("inf")]), "targets[2].ra_deg"),
        (dict(dec_deg=[0.0, 90.5, 0.0]), "targets[1].dec_deg"),
        (dict(dec_deg=[0.0, 0.0, float("-inf")]), "targets[2].dec_deg"),
        (dict(priority=[1, 0, 1]), "targets[1].priority"),
        (dict(priority=[1, 1, 2**32]), "targets[2].priority"),
        (dict(priority=[1, 1.5, 1]), "targets[1].priority"),
        (dict(priority=[True, 1, 1]), "targets[0].priority"),
        (dict(dec_deg=[0.0, 0.0]), "targets.dec_deg"),
    ],
)
def test_validate_rejects_bad_targets_naming_the_field(change, field):
    kwargs = {**GOOD, **change}
    if change.get("ids") == []:
        kwargs = dict(ids=[], ra_deg=[], dec_deg=[], priority=[])
    with pytest.raises(InputError) as e:
        validate_sky_targets(**kwargs)
    assert e.value.field == field
    assert isinstance(e.value, ValueError)
    assert field in str(e.value)
