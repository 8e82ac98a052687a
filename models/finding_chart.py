"""Finding charts: an astronomer's FITS image, resampled about a pointing as the sky is seen.

:func:`read_fits_image` finds the first 2-D image of a FITS file that has a celestial WCS
(a 2MASS or Pan-STARRS cut-out, say); :func:`render_chart` resamples it onto a square grid of
standard coordinates about a centre and stretches it so that faint stars show.

The chart's geometry (the contract the page, the CLI and ``POST /v1/finding-charts`` share):

* ``size_px`` x ``size_px`` pixels spanning ``2 * half_width_arcmin`` on each side, a gnomonic
  (TAN) projection about (``ra_deg``, ``dec_deg``), the centre at the middle of the grid.
* Its up direction points to position angle ``up_pa_deg`` (East of North) and its left to
  ``up_pa_deg + 90``: the sky as seen, East 90 degrees counter-clockwise of North. With
  ``u`` the coordinate increasing leftwards and ``v`` upwards, pixel (col, row), row 0 at the
  top, is at ``u = h - (col + 0.5) * 2h / size_px``, ``v = h - (row + 0.5) * 2h / size_px``
  and ``xi = u cos PA + v sin PA``, ``eta = -u sin PA + v cos PA`` (xi East, eta North).
  These are the focal-plane equations of :mod:`models.sky` with (u, v) as (x, y): at
  ``up_pa_deg`` = the pointing's PA, up is focal-plane +y and left is focal-plane +x, so a
  chart drawn under the focal plane (+x leftwards) lines up with it.
* Pixels the image does not cover are NaN (transparent in the PNG).

The image's own WCS places every pixel (astropy/wcslib: CD or PC matrices, rotations,
flipped axes, SIP distortions, Galactic or FK4 frames), so North and East follow the image.
"""

from __future__ import annotations

import gzip
import io
import math
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from astropy.io import fits
from astropy.wcs import WCS, FITSFixedWarning

from models.errors import InputError
from models.sky import focal_mm_to_sky

#: Most pixels of an image read by :func:`read_fits_image` (a 4096 x 4096 cut-out).
MAX_IMAGE_PIXELS = 4096 * 4096
#: Most pixels on a side of a chart.
MAX_SIZE_PX = 4096
#: Largest half width of a chart: its corners stay well inside the gnomonic hemisphere.
MAX_HALF_WIDTH_ARCMIN = 1800.0
#: Grey level (0..1) of zscale's upper limit; brighter pixels share the rest (see :func:`stretch`).
ZSCALE_TOP = 0.85
#: Softening of the asinh stretch inside the zscale limits (astropy's default).
ASINH_A = 0.1
_ARCSEC_PER_ARCMIN = 60.0
#: Bytes a decompressed file may hold beyond its pixels: headers and other HDUs.
_HEADER_ALLOWANCE_BYTES = 16 * 2880 * 36


@dataclass(frozen=True)
class FitsImage:
    """A 2-D sky image: ``data[row, col]`` (FITS axis 2, axis 1; NaN where blank) and the
    celestial ``wcs`` whose pixel (0, 0) is ``data[0, 0]``."""

    data: np.ndarray
    wcs: WCS

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.data.shape[0]), int(self.data.shape[1])


@dataclass(frozen=True)
class ChartImage:
    """A rendered chart: ``values[row, col]`` in 0..1 (1 = brightest sky, NaN = not covered by
    the image; row 0 at the top) and the geometry it was drawn with (see the module doc)."""

    values: np.ndarray
    ra_deg: float
    dec_deg: float
    half_width_arcmin: float
    up_pa_deg: float

    @property
    def size_px(self) -> int:
        return int(self.values.shape[0])

    @property
    def scale_arcmin_per_px(self) -> float:
        return 2.0 * self.half_width_arcmin / self.size_px

    @property
    def extent_arcmin(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) of the chart in (u, v) arcmin, u increasing leftwards: the
        ``extent`` of matplotlib's ``imshow`` on axes whose x grows to the left."""
        h = self.half_width_arcmin
        return (h, -h, -h, h)

    def pixel_of(self, ra_deg: float, dec_deg: float) -> tuple[float, float]:
        """(col, row) of a sky position, in index units (pixel centres at integers), so that
        ``values[round(row), round(col)]`` is the pixel under it."""
        xi, eta = standard_coordinates_arcmin(self.ra_deg, self.dec_deg, ra_deg, dec_deg)
        p = math.radians(self.up_pa_deg)
        u = xi * math.cos(p) - eta * math.sin(p)
        v = xi * math.sin(p) + eta * math.cos(p)
        s = self.scale_arcmin_per_px
        return (self.half_width_arcmin - u) / s - 0.5, (self.half_width_arcmin - v) / s - 0.5

    def orientation_line(self) -> str:
        """One line stating how the chart is oriented, for its caption."""
        if self.up_pa_deg % 360.0 == 0.0:
            return "Sky as seen: North up, East left"
        return (f"Sky as seen: up is PA {self.up_pa_deg:g} deg East of North, "
                "East 90 deg counter-clockwise of North")

    def to_png(self) -> bytes:
        """The chart as an 8-bit grey + alpha PNG: inverted grey (sky light, stars dark) so that
        coloured markers drawn over it stay readable; alpha 0 where the image has no data."""
        from PIL import Image

        v = self.values
        covered = np.isfinite(v)
        grey = np.where(covered, np.rint(255.0 * (1.0 - np.clip(np.nan_to_num(v), 0, 1))), 255)
        la = np.stack([grey.astype(np.uint8), np.where(covered, 255, 0).astype(np.uint8)], -1)
        buf = io.BytesIO()
        Image.fromarray(la, mode="LA").save(buf, format="PNG")
        return buf.getvalue()


def standard_coordinates_arcmin(ra0_deg: float, dec0_deg: float, ra_deg: float,
                                dec_deg: float) -> tuple[float, float]:
    """Gnomonic standard coordinates (xi East, eta North) in arcmin of (ra, dec) about
    (ra0, dec0)."""
    a0, d0 = math.radians(ra0_deg), math.radians(dec0_deg)
    a, d = math.radians(ra_deg), math.radians(dec_deg)
    cos_c = math.sin(d0) * math.sin(d) + math.cos(d0) * math.cos(d) * math.cos(a - a0)
    if cos_c <= 0.0:
        raise InputError("ra_deg", "the position is 90 deg or more from the chart's centre")
    xi = math.cos(d) * math.sin(a - a0) / cos_c
    eta = (math.cos(d0) * math.sin(d) - math.sin(d0) * math.cos(d) * math.cos(a - a0)) / cos_c
    k = math.degrees(1.0) * _ARCSEC_PER_ARCMIN
    return xi * k, eta * k


# --------------------------------------------------------------------------- reading


def load_fits_image(path: str | Path, *, max_pixels: int = MAX_IMAGE_PIXELS,
                    field: str = "image") -> FitsImage:
    """:func:`read_fits_image` of a file on disk."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(field, f"cannot read {path}: {exc.strerror or exc}") from exc
    return read_fits_image(raw, max_pixels=max_pixels, field=field)


def read_fits_image(raw: bytes, *, max_pixels: int = MAX_IMAGE_PIXELS,
                    field: str = "image") -> FitsImage:
    """The first HDU of the FITS bytes ``raw`` holding a 2-D image (other axes of length 1 are
    dropped) with a celestial WCS. Raises :class:`InputError` naming ``field``: "not a FITS
    image", "the image has no celestial WCS", "image larger than N pixels". The size is
    checked from the header before any data is read. A gzip-compressed file (``.fits.gz``) is
    decompressed first, to at most the bytes of ``max_pixels`` 64-bit pixels and their
    headers."""
    raw = _gunzip(raw, max_pixels, field)
    if not raw.startswith(b"SIMPLE  ="):
        raise InputError(field, "not a FITS image: the file does not start with a FITS header "
                         "('SIMPLE  =' in its first bytes)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # astropy's notes on non-standard headers
        try:
            hdus = fits.open(io.BytesIO(raw), memmap=False, lazy_load_hdus=True)
            found = _first_image(hdus, max_pixels, field)
        except (InputError, MemoryError):
            raise
        except Exception as exc:  # noqa: BLE001 - astropy refuses odd files with many kinds
            raise InputError(field, f"not a FITS image: {_reason(exc)}") from exc
    if found is None:
        raise InputError(field, "not a FITS image: no HDU holds a 2-D image")
    return found


def _gunzip(raw: bytes, max_pixels: int, field: str) -> bytes:
    """``raw`` decompressed when it is gzip data, else ``raw``; refused past the bound."""
    if raw[:2] != b"\x1f\x8b":
        return raw
    most = 8 * max_pixels + _HEADER_ALLOWANCE_BYTES
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(raw)) as z:
            plain = z.read(most + 1)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(field, f"not a FITS image: bad gzip data ({_reason(exc)})") from exc
    if len(plain) > most:
        raise InputError(field, f"image larger than {max_pixels} pixels (more than {most} "
                         "bytes once decompressed)")
    return plain


def _reason(exc: BaseException) -> str:
    return (str(exc) or type(exc).__name__)[:160]


def _first_image(hdus: fits.HDUList, max_pixels: int, field: str) -> FitsImage | None:
    """The first 2-D image HDU with a celestial WCS; None when no HDU holds a 2-D image."""
    saw_image = False
    for hdu in hdus:
        if not hdu.is_image:
            continue
        axes = _image_axes(hdu.header)
        if axes is None:
            continue
        saw_image = True
        n_px = axes[0][1] * axes[1][1]
        if n_px > max_pixels:
            raise InputError(field, f"image larger than {max_pixels} pixels "
                             f"({axes[0][1]} x {axes[1][1]} = {n_px})")
        wcs = _celestial_wcs(hdu.header, axes)
        if wcs is None:
            continue
        return FitsImage(_image_data(hdu, axes), wcs)
    if saw_image:
        raise InputError(field, "the image has no celestial WCS (no RA/Dec or other "
                         "longitude/latitude axes with a projection in its header)")
    return None


def _image_axes(header: fits.Header) -> list[tuple[int, int]] | None:
    """The (FITS axis index 0-based, length) of the two axes longer than 1; None unless there
    are exactly two."""
    naxis = int(header.get("NAXIS", 0))
    if naxis < 2:
        return None
    lengths = [int(header.get(f"NAXIS{i + 1}", 0)) for i in range(naxis)]
    big = [(i, n) for i, n in enumerate(lengths) if n > 1]
    if len(big) != 2 or any(n < 1 for n in lengths):
        return None
    return big


def _celestial_wcs(header: fits.Header, axes: list[tuple[int, int]]) -> WCS | None:
    """The header's WCS over the image's two axes, when they are its celestial axes."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FITSFixedWarning)
            wcs = WCS(header)
            if not wcs.has_celestial:
                return None
            if wcs.naxis == 2:
                return wcs
            if sorted((wcs.wcs.lng, wcs.wcs.lat)) != [axes[0][0], axes[1][0]]:
                return None
            return wcs.celestial
    except Exception:  # noqa: BLE001 - wcslib refuses odd headers with many kinds
        return None


def _image_data(hdu: Any, axes: list[tuple[int, int]]) -> np.ndarray:
    """The HDU's pixels as a float32 (rows, cols) array, NaN for blanks."""
    data = hdu.data
    if data is None:
        raise InputError("image", "not a FITS image: the image HDU holds no data")
    arr = np.asarray(data, dtype=np.float32).reshape(axes[1][1], axes[0][1])
    return np.where(np.isfinite(arr), arr, np.float32(np.nan))


# --------------------------------------------------------------------------- rendering


def render_chart(image: FitsImage, ra_deg: float, dec_deg: float, half_width_arcmin: float,
                 up_pa_deg: float = 0.0, size_px: int = 512) -> ChartImage:
    """``image`` resampled (bilinearly) onto the chart grid described in the module doc and
    stretched by :func:`stretch`."""
    _check_chart(ra_deg, dec_deg, half_width_arcmin, up_pa_deg, size_px)
    h = float(half_width_arcmin)
    step = 2.0 * h / size_px
    centres = h - (np.arange(size_px) + 0.5) * step
    u, v = np.meshgrid(centres, centres)  # [row, col]: u per column (leftwards), v per row (up)
    ra, dec = focal_mm_to_sky(u, v, ra_deg, dec_deg, _ARCSEC_PER_ARCMIN, up_pa_deg)
    col, row = _world_to_pixel(image.wcs, ra, dec)
    values = _sample(image.data, col, row)
    return ChartImage(stretch(values), float(ra_deg), float(dec_deg), h, float(up_pa_deg))


def _check_chart(ra_deg: float, dec_deg: float, half_width_arcmin: float, up_pa_deg: float,
                 size_px: int) -> None:
    for name, value in (("ra_deg", ra_deg), ("dec_deg", dec_deg),
                        ("half_width_arcmin", half_width_arcmin), ("up_pa_deg", up_pa_deg)):
        if not math.isfinite(float(value)):
            raise InputError(name, f"must be finite, got {value!r}")
    if not 0.0 <= ra_deg <= 360.0:
        raise InputError("ra_deg", f"must be in [0, 360], got {ra_deg!r}")
    if not -90.0 <= dec_deg <= 90.0:
        raise InputError("dec_deg", f"must be in [-90, 90], got {dec_deg!r}")
    if not 0.0 < half_width_arcmin <= MAX_HALF_WIDTH_ARCMIN:
        raise InputError("half_width_arcmin", f"must be > 0 and <= {MAX_HALF_WIDTH_ARCMIN:g}, "
                         f"got {half_width_arcmin!r}")
    if int(size_px) != size_px or not 1 <= size_px <= MAX_SIZE_PX:
        raise InputError("size_px", f"must be an integer in [1, {MAX_SIZE_PX}], got {size_px!r}")


def _world_to_pixel(wcs: WCS, ra_deg: np.ndarray, dec_deg: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Image pixel (col, row), 0-based, of ICRS positions, through the image's WCS (in its own
    celestial frame; ICRS and FK5 J2000 are taken as one, they differ by tens of mas)."""
    lon, lat = _in_frame_of(wcs, ra_deg.ravel(), dec_deg.ravel())
    world = (lon, lat) if wcs.wcs.lng == 0 else (lat, lon)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            col, row = wcs.all_world2pix(*world, 0, quiet=True)
        except Exception as exc:  # noqa: BLE001 - wcslib's errors on degenerate headers
            raise InputError("image", f"its WCS cannot place the chart's pixels: "
                             f"{_reason(exc)}") from exc
    return np.asarray(col).reshape(ra_deg.shape), np.asarray(row).reshape(ra_deg.shape)


def _in_frame_of(wcs: WCS, ra_deg: np.ndarray, dec_deg: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    from astropy.coordinates import FK5, ICRS, SkyCoord
    from astropy.wcs.utils import wcs_to_celestial_frame

    try:
        frame = wcs_to_celestial_frame(wcs)
    except ValueError:  # a celestial frame astropy does not name: read as ICRS
        return ra_deg, dec_deg
    if isinstance(frame, ICRS) or (isinstance(frame, FK5) and frame.equinox.jyear == 2000.0):
        return ra_deg, dec_deg
    sph = SkyCoord(ra_deg, dec_deg, unit="deg", frame="icrs").transform_to(frame).spherical
    return np.asarray(sph.lon.deg), np.asarray(sph.lat.deg)


def _sample(data: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``data`` at (col, row); NaN outside the image (a pixel covers
    +-0.5 about its centre) and next to blank pixels."""
    from scipy.ndimage import map_coordinates

    n_rows, n_cols = data.shape
    inside = ((col >= -0.5) & (col <= n_cols - 0.5) & (row >= -0.5) & (row <= n_rows - 0.5)
              & np.isfinite(col) & np.isfinite(row))
    out = np.full(col.shape, np.nan)
    if inside.any():
        out[inside] = map_coordinates(data, [row[inside], col[inside]], order=1,
                                      mode="nearest", output=np.float64)
    return out


def stretch(values: np.ndarray) -> np.ndarray:
    """Grey levels 0..1 of ``values`` (NaN stays NaN): zscale's limits (lo, hi), then an asinh
    stretch that maps lo..hi onto 0..:data:`ZSCALE_TOP` (faint stars near the sky level get
    most of the grey levels); pixels above hi, the cores of bright stars, share the rest on a
    logarithmic scale instead of saturating, so that a star's peak stays its brightest
    pixel."""
    from astropy.visualization import ZScaleInterval

    finite = np.isfinite(values)
    if not finite.any():
        return np.full(values.shape, np.nan)
    lo, hi = ZScaleInterval().get_limits(values[finite])
    if not hi > lo:
        hi = lo + max(abs(lo), 1.0) * 1e-6
    x = np.maximum((np.where(finite, values, lo) - lo) / (hi - lo), 0.0)
    faint = np.arcsinh(np.minimum(x, 1.0) / ASINH_A) / np.arcsinh(1.0 / ASINH_A)
    top = float(x.max())
    if top <= 1.0:
        grey = faint
    else:
        bright = np.log(np.maximum(x, 1.0)) / math.log(top)
        grey = np.where(x <= 1.0, ZSCALE_TOP * faint, ZSCALE_TOP + (1.0 - ZSCALE_TOP) * bright)
    return np.where(finite, grey, np.nan)
