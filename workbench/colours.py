"""Honest colour scales: one place decides a quantity's colour range, its map and what it hides.

A colour scale teaches only if a student can trust it:

- the range comes from robust percentiles of the *defined* values, so one value of 1e153 at a
  crease (or 55 where delta_1 = f/|grad f| meets grad f = 0) does not wash out the rest, and the
  fraction of values the range clips is stated next to it;
- values that are undefined (NaN: grad f = 0, creases; or marked by a ``defined`` mask such as
  :class:`pyfrep_core.curvature.Curvatures` ``.defined``) never enter the range: they are
  counted and drawn in a neutral colour (:data:`UNDEFINED_COLOUR`);
- a one-signed quantity (a Gaussian curvature that is <= 0 everywhere, a distance error) gets a
  one-sided sequential map; a quantity of both signs a diverging map centred on 0, so its
  white means 0 and nothing else.

Used by the 3-D views (curvature, normal velocity) and the slice plots of the workbench;
notebooks import it for their figures (``from workbench.colours import colour_range``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DIVERGING", "SEQUENTIAL", "UNDEFINED_COLOUR", "ColourRange", "colour_range"]

DIVERGING = "RdBu_r"  # red > 0, blue < 0, white exactly 0
SEQUENTIAL = "viridis"  # one-signed quantities: dark = low, yellow = high
UNDEFINED_COLOUR = "#9a9a9a"  # neutral grey, outside both maps
SIGN_TOLERANCE = 0.01  # a range whose minority sign is this small a fraction of the other is one-signed


@dataclass(frozen=True)
class ColourRange:
    """A colour range and what it leaves out (see :func:`colour_range`).

    Attributes
    ----------
    lo, hi : the range (``lo < hi``); values outside are drawn with the end colours.
    cmap : matplotlib colour-map name (:data:`DIVERGING` or :data:`SEQUENTIAL`).
    diverging : True when the map is centred on 0 (``lo == -hi``).
    clipped : fraction (0..1) of the defined values outside ``[lo, hi]``.
    undefined : how many values were undefined (NaN or masked): not in the range, drawn grey.
    total : how many values there were.
    """

    lo: float
    hi: float
    cmap: str
    diverging: bool
    clipped: float
    undefined: int
    total: int

    @property
    def clim(self) -> tuple[float, float]:
        return (self.lo, self.hi)

    def describe(self, name: str = "", unit: str = "") -> str:
        """One line for a status or a caption: range, unit, clipped fraction, undefined count.

        Examples
        --------
        >>> colour_range(np.array([1.0, 2.0, np.nan, 3.0])).describe("K", "1/length^2")
        'K in [1, 3] 1/length^2, 0% of 3 values clipped, 1 undefined (grey)'
        """
        head = f"{name} in " if name else ""
        unit = f" {unit}" if unit else ""
        defined = self.total - self.undefined
        text = f"{head}[{self.lo:.3g}, {self.hi:.3g}]{unit}, {100 * self.clipped:.2g}% of {defined} values clipped"
        if self.undefined:
            text += f", {self.undefined} undefined (grey)"
        return text


def colour_range(
    values: np.ndarray,
    defined: np.ndarray | None = None,
    percentiles: tuple[float, float] = (1.0, 99.0),
    diverging: bool | None = None,
) -> ColourRange:
    """The colour range of ``values``: robust percentiles of the defined values, the map by sign.

    Parameters
    ----------
    values : array (any shape) of the quantity; NaN and +-inf count as undefined.
    defined : optional bool mask of the same shape; False marks more undefined values
        (e.g. ``Curvatures.defined``).
    percentiles : lower and upper percentile of the defined values bounding the range.
    diverging : force (True) or forbid (False) a diverging map centred on 0; None decides by
        sign: one-sided when the range's two percentiles have the same sign, or one is under
        :data:`SIGN_TOLERANCE` times the other in size (then the range starts at 0).

    Returns
    -------
    ColourRange
        With a diverging map the range is ``[-t, t]``, t the larger magnitude of the two
        percentiles; with a one-sided map it is the percentiles themselves.  When the two
        percentiles are equal (most values the same) the range spans all defined values; a
        constant or empty input gets a small range around its value (0 when empty).

    Examples
    --------
    One value of 1e153 at a crease does not set the scale, and is counted as clipped:

    >>> h = np.r_[np.linspace(-1.0, 2.0, 99), 1e153]
    >>> r = colour_range(h, percentiles=(1, 99))
    >>> r.cmap, r.diverging, r.hi, r.lo == -r.hi, r.clipped
    ('RdBu_r', True, 2.0, True, 0.01)

    A one-signed quantity (Gaussian curvature of a minimal surface, <= 0) gets a one-sided map,
    and an undefined point (NaN) is counted, not ranged:

    >>> k = np.r_[-np.linspace(0.0, 4.0, 101), np.nan]
    >>> r = colour_range(k, percentiles=(0, 100))
    >>> r.cmap, r.lo, r.hi, r.undefined
    ('viridis', -4.0, 0.0, 1)

    Most values 0, a few not (a parameter that moves one small feature): the range shows them.

    >>> colour_range(np.r_[np.zeros(98), 1.0, -3.0]).clim
    (-3.0, 3.0)

    A sliver of the other sign (1e-4 against 1) does not make a quantity two-signed:

    >>> r = colour_range(np.r_[-1e-4, np.linspace(0.0, 1.0, 100)], percentiles=(0, 100))
    >>> r.cmap, r.clim, round(r.clipped, 4)
    ('viridis', (0.0, 1.0), 0.0099)
    """
    values = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(values)
    if defined is not None:
        defined = np.asarray(defined, dtype=bool)
        if defined.shape != values.shape:
            raise ValueError(f"colour_range: defined has shape {defined.shape}, values {values.shape}")
        ok &= defined
    lo_p, hi_p = float(percentiles[0]), float(percentiles[1])
    if not 0.0 <= lo_p < hi_p <= 100.0:
        raise ValueError(f"colour_range: percentiles must satisfy 0 <= lo < hi <= 100, got {percentiles!r}")
    good = values[ok]
    total, undefined = int(values.size), int(values.size - good.size)
    if good.size == 0:
        return ColourRange(-1.0, 1.0, DIVERGING, True, 0.0, undefined, total)
    # nearest order statistics, not interpolated: the interpolated 99th percentile of 99 values
    # and one 1e153 is itself 1e151
    lo, hi = (float(v) for v in np.percentile(good, (lo_p, hi_p), method="nearest"))
    if not hi > lo:  # most values equal (a parameter moving a small part of a surface): all of them
        lo, hi = float(good.min()), float(good.max())
    if diverging is None:
        # one-signed up to a sliver: values of the minority sign under 1 % of the majority's size
        # are rounding or vertices next to a crease (K of the Fig. 1 part is >= 0 on every piece)
        diverging = lo < 0.0 < hi and min(-lo, hi) > SIGN_TOLERANCE * max(-lo, hi)
        if not diverging and lo < 0.0 < hi:
            lo, hi = (0.0, hi) if hi > -lo else (lo, 0.0)
    if diverging:
        top = max(abs(lo), abs(hi))
        lo, hi = -top, top
    if not hi > lo:  # a constant: a small range around it, so the colour bar can be drawn
        pad = max(abs(lo), 1.0) * 1e-9
        lo, hi = lo - pad, hi + pad
    slack = 1e-9 * max(abs(lo), abs(hi))  # rounding (K = -1e-17 on a plane) is not clipping
    clipped = float(np.mean((good < lo - slack) | (good > hi + slack)))
    return ColourRange(lo, hi, DIVERGING if diverging else SEQUENTIAL, bool(diverging), clipped, undefined, total)
