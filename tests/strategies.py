"""Hypothesis strategies for the property tests: random CSG trees over the catalogue, random points.

A tree is a small immutable object that is called like a model (``tree(x)`` -> values) and whose
``repr`` is the Python expression that builds it, so a falsifying example reads as code that can be
pasted into a session (``union_m(sphere(translate(x, offset=(0.5, 0.0, 0.0)), ...), ..., m=1.0)``).

Parameters are drawn from ranges where every function is defined (radii and semi-axes > 0, scale
factors away from 0, distinct twist and taper ends, nonzero directions), so a tree never trips
the catalogue's parameter checks.  The ranges also bound the magnitudes: points lie in
``[-POINT_BOX, POINT_BOX]^3``, every transform changes a coordinate by at most a factor 2 (or a
rotation), every primitive is a polynomial of degree <= 4 in coordinates of size <= 3 / 0.2, an
R_m operation raises its operands to a degree <= m + 1 <= 3 and a tree has at most ``DEPTH``
operations on a path, so the largest float64 value is far below the overflow threshold (1e308).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import pyfrep_core as P
from pyfrep_core import sdf

POINT_BOX = 2.0  # random points lie in [-2, 2]^3
DEPTH = 3  # operations and transforms on a path from the root to a leaf


def _fmt(value) -> str:
    if isinstance(value, tuple):
        return "(" + ", ".join(_fmt(v) for v in value) + ("," if len(value) == 1 else "") + ")"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return repr(value)


def _args(kwargs: tuple) -> str:
    return "".join(f", {k}={_fmt(v)}" for k, v in kwargs)


@dataclass(frozen=True)
class Leaf:
    """A primitive ``fn(x, **kwargs)``; ``name`` is how it is spelt in code (``sphere``, ``sdf.box``)."""

    name: str
    fn: Callable
    kwargs: tuple

    def __call__(self, x):
        return self.fn(x, **dict(self.kwargs))

    def code(self, x: str = "x") -> str:
        return f"{self.name}({x}{_args(self.kwargs)})"

    def __repr__(self) -> str:
        return self.code()


@dataclass(frozen=True)
class Op:
    """An operation on the values of its children: ``fn(child_1(x), ..., **kwargs)``."""

    name: str
    fn: Callable
    children: tuple
    kwargs: tuple = ()

    def __call__(self, x):
        return self.fn(*(c(x) for c in self.children), **dict(self.kwargs))

    def code(self, x: str = "x") -> str:
        return f"{self.name}({', '.join(c.code(x) for c in self.children)}{_args(self.kwargs)})"

    def __repr__(self) -> str:
        return self.code()


@dataclass(frozen=True)
class Warp:
    """A transform of the points under a subtree: ``child(fn(x, **kwargs))``."""

    name: str
    fn: Callable
    child: object
    kwargs: tuple

    def __call__(self, x):
        return self.child(self.fn(x, **dict(self.kwargs)))

    def code(self, x: str = "x") -> str:
        return self.child.code(f"{self.name}({x}{_args(self.kwargs)})")

    def __repr__(self) -> str:
        return self.code()


# ----------------------------------------------------------------------------- parameters


def real(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


def signed(lo: float, hi: float) -> st.SearchStrategy[float]:
    """A number whose magnitude lies in [lo, hi], of either sign."""
    return st.tuples(st.sampled_from((1.0, -1.0)), real(lo, hi)).map(lambda t: t[0] * t[1])


COORD = real(-1.0, 1.0)
VEC3 = st.tuples(COORD, COORD, COORD)
DIRECTION = VEC3.filter(lambda v: math.hypot(*v) > 0.1)
RADIUS = real(0.1, 1.5)
SEMI_AXIS = real(0.2, 1.5)
EXPONENT = real(0.5, 3.0)
ANGLE = real(-math.pi, math.pi)
FACTOR = signed(0.5, 2.0)


def _distinct_ends(gap: float = 0.1) -> st.SearchStrategy[tuple[float, float]]:
    return st.tuples(COORD, COORD).filter(lambda t: abs(t[0] - t[1]) >= gap)


def _call(name: str, fn: Callable, kind: type, **params: st.SearchStrategy) -> st.SearchStrategy:
    return st.fixed_dictionaries(params).map(lambda kw: kind(name, fn, tuple(kw.items())))


def _centers(fn_name: str, fn: Callable, **per_center: st.SearchStrategy) -> st.SearchStrategy:
    """A multi-center primitive (blobby, metaBall, soft) with K = 1..3 centers; T is a scalar."""

    def build(k: int) -> st.SearchStrategy:
        lists = {n: st.lists(s, min_size=k, max_size=k) for n, s in per_center.items()}
        return _call(fn_name, fn, Leaf, x0=st.lists(COORD, min_size=k, max_size=k),
                     y0=st.lists(COORD, min_size=k, max_size=k), z0=st.lists(COORD, min_size=k, max_size=k),
                     **lists, T=real(0.05, 1.0))  # fmt: skip

    return st.integers(1, 3).flatmap(build)


# ----------------------------------------------------------------------------- the catalogue

_FREP_LEAVES = [
    _call("sphere", P.sphere, Leaf, center=VEC3, r=RADIUS),
    _call("ellipsoid", P.ellipsoid, Leaf, center=VEC3, a=SEMI_AXIS, b=SEMI_AXIS, c=SEMI_AXIS),
    *(_call(n, getattr(P, n), Leaf, center=VEC3, r=RADIUS) for n in ("cylX", "cylY", "cylZ")),
    _call("block", P.block, Leaf, vertex=VEC3, dx=SEMI_AXIS, dy=SEMI_AXIS, dz=SEMI_AXIS),
    *(_call(n, getattr(P, n), Leaf, center=VEC3, R=real(0.0, 1.2), r=RADIUS) for n in ("torusX", "torusY", "torusZ")),
    *(_call(n, getattr(P, n), Leaf, center=VEC3, a=SEMI_AXIS, b=SEMI_AXIS) for n in ("ellCylX", "ellCylY", "ellCylZ")),
    *(_call(n, getattr(P, n), Leaf, center=VEC3, R=SEMI_AXIS) for n in ("coneX", "coneY", "coneZ")),
    *(
        _call(n, getattr(P, n), Leaf, center=VEC3, a=SEMI_AXIS, b=SEMI_AXIS)
        for n in ("ellConeX", "ellConeY", "ellConeZ")
    ),
    _call("superEll", P.superEll, Leaf, center=VEC3, a=SEMI_AXIS, b=SEMI_AXIS, c=SEMI_AXIS, s1=EXPONENT, s2=EXPONENT),
    _call(
        "superQuadric",
        P.superQuadric,
        Leaf,
        e=st.tuples(EXPONENT, EXPONENT),
        a=st.tuples(SEMI_AXIS, SEMI_AXIS, SEMI_AXIS),
        r=st.tuples(ANGLE, ANGLE, ANGLE),
        t=VEC3,
    ),
    _centers("blobby", P.blobby, a=real(0.5, 4.0), b=real(0.2, 2.0)),
    _centers("metaBall", P.metaBall, b=real(0.2, 2.0), d=real(0.3, 2.0)),
    _centers("soft", P.soft, d=real(0.3, 2.0)),
    _call("noiseG", P.noiseG, Leaf, amp=real(0.0, 1.0), freq=real(0.1, 4.0), phase=real(-2.0, 2.0)),
]

_SDF_LEAVES = [
    _call("sdf.sphere", sdf.sphere, Leaf, center=VEC3, r=RADIUS),
    _call("sdf.plane", sdf.plane, Leaf, normal=DIRECTION, point=VEC3),
    _call("sdf.box", sdf.box, Leaf, b=st.tuples(SEMI_AXIS, SEMI_AXIS, SEMI_AXIS), center=VEC3),
    _call("sdf.block", sdf.block, Leaf, vertex=VEC3, dx=SEMI_AXIS, dy=SEMI_AXIS, dz=SEMI_AXIS),
    _call(
        "sdf.roundedBox",
        sdf.roundedBox,
        Leaf,
        b=st.tuples(SEMI_AXIS, SEMI_AXIS, SEMI_AXIS),
        radius=real(0.0, 0.5),
        center=VEC3,
    ),
    _call("sdf.torus", sdf.torus, Leaf, R=real(0.0, 1.2), r=RADIUS, center=VEC3, axis=st.sampled_from("xyz")),
    *(
        _call(f"sdf.{n}", getattr(sdf, n), Leaf, center=VEC3, R=real(0.0, 1.2), r=RADIUS)
        for n in ("torusX", "torusY", "torusZ")
    ),
    st.tuples(VEC3, VEC3, RADIUS)
    .filter(lambda t: math.dist(t[0], t[1]) >= 0.1)
    .map(lambda t: Leaf("sdf.capsule", sdf.capsule, (("a", t[0]), ("b", t[1]), ("radius", t[2])))),
    _call("sdf.cylinder", sdf.cylinder, Leaf, center=VEC3, u=DIRECTION, r=RADIUS),
    *(
        _call(f"sdf.{n}", getattr(sdf, n), Leaf, center=VEC3, r=RADIUS)
        for n in ("cylinderX", "cylinderY", "cylinderZ", "cylX", "cylY", "cylZ", "coneX", "coneY", "coneZ")
    ),
    st.tuples(VEC3, VEC3, RADIUS)
    .filter(lambda t: math.dist(t[0], t[1]) >= 0.1)
    .map(lambda t: Leaf("sdf.cappedCylinder", sdf.cappedCylinder, (("a", t[0]), ("b", t[1]), ("radius", t[2])))),
    st.tuples(VEC3, VEC3, real(0.0, 1.0), real(0.0, 1.0))
    .filter(lambda t: math.dist(t[0], t[1]) >= 0.1 and t[2] + t[3] >= 0.1)
    .map(lambda t: Leaf("sdf.cappedCone", sdf.cappedCone, (("a", t[0]), ("b", t[1]), ("ra", t[2]), ("rb", t[3])))),
    st.tuples(SEMI_AXIS, real(0.05, 0.3), VEC3)
    .filter(lambda t: t[1] < t[0])
    .map(lambda t: Leaf("sdf.frame", sdf.frame, (("side_length", t[0]), ("thickness", t[1]), ("center", t[2])))),
]

LEAVES = st.one_of(*_FREP_LEAVES, *_SDF_LEAVES)

M = real(0.0, 2.0)  # R_m smoothness order
EXTENT = signed(0.2, 2.0)  # blend extents a1, a2, a3 (nonzero; their sign does not matter)
AMPLITUDE = real(-1.0, 1.0)  # blend amplitude a0
WIDTH = real(0.0, 0.5)  # sdf smooth-operation width k (0: the sharp operation)

_PLAIN_BINARY = (
    ("union", P.union),
    ("intersection", P.intersection),
    ("difference", P.difference),
    ("union_min_max", P.union_min_max),
    ("intersection_min_max", P.intersection_min_max),
    ("difference_min_max", P.difference_min_max),
    ("sdf.union", sdf.union),
    ("sdf.intersection", sdf.intersection),
    ("sdf.difference", sdf.difference),
)


def binary_ops(a: st.SearchStrategy, b: st.SearchStrategy | None = None) -> st.SearchStrategy[Op]:
    """Every two-operand operation of the catalogue on operands drawn from ``a`` and ``b``."""
    b = a if b is None else b
    pair = st.tuples(a, b)

    def op(name: str, fn: Callable, **params: st.SearchStrategy) -> st.SearchStrategy[Op]:
        return st.tuples(pair, st.fixed_dictionaries(params)).map(lambda t: Op(name, fn, t[0], tuple(t[1].items())))

    return st.one_of(
        *(op(n, f) for n, f in _PLAIN_BINARY),
        *(op(n, getattr(P, n), m=M) for n in ("union_m", "intersection_m", "difference_m")),
        *(
            op(n, getattr(P, n), a0=AMPLITUDE, a1=EXTENT, a2=EXTENT)
            for n in ("blendUnion", "blendIntersection", "blendDifference")
        ),
        *(op(f"sdf.{n}", getattr(sdf, n), k=WIDTH) for n in ("smoothUnion", "smoothIntersection", "smoothDifference")),
    )


def _ternary_ops(sub: st.SearchStrategy) -> st.SearchStrategy[Op]:
    params = st.fixed_dictionaries({"a0": AMPLITUDE, "a1": EXTENT, "a2": EXTENT, "a3": EXTENT})
    return st.tuples(st.sampled_from(("boundBlendUnion", "boundBlendIntersection")), sub, sub, sub, params).map(
        lambda t: Op(t[0], getattr(P, t[0]), t[1:4], tuple(t[4].items()))
    )


def _unary_ops(sub: st.SearchStrategy) -> st.SearchStrategy[Op]:
    def op(name: str, fn: Callable, **params: st.SearchStrategy) -> st.SearchStrategy[Op]:
        return st.tuples(sub, st.fixed_dictionaries(params)).map(lambda t: Op(name, fn, (t[0],), tuple(t[1].items())))

    return st.one_of(
        op("negate", P.negate),
        op("offset", P.offset, d=real(-0.5, 0.5)),
        op("shell", P.shell, thickness=real(0.05, 0.5)),
        op("sdf.negate", sdf.negate),
        op("sdf.dilate", sdf.dilate, r=real(0.0, 0.5)),
        op("sdf.erode", sdf.erode, r=real(0.0, 0.5)),
        op("sdf.shell", sdf.shell, e=real(0.05, 0.5)),
    )


def _warps(sub: st.SearchStrategy) -> st.SearchStrategy[Warp]:
    def warp(name: str, fn: Callable, **params: st.SearchStrategy) -> st.SearchStrategy[Warp]:
        return st.tuples(sub, st.fixed_dictionaries(params)).map(lambda t: Warp(name, fn, t[0], tuple(t[1].items())))

    def ends(name: str, axis: str, values: st.SearchStrategy) -> st.SearchStrategy[Warp]:
        # twist/taper: distinct ends t1 != t2 and their two values
        return st.tuples(sub, _distinct_ends(), values).map(
            lambda t: Warp(
                name,
                getattr(P, name),
                t[0],
                ((f"{axis}1", t[1][0]), (f"{axis}2", t[1][1]), *t[2]),
            )
        )

    same_sign = st.tuples(st.sampled_from((1.0, -1.0)), real(0.5, 2.0), real(0.5, 2.0)).map(
        lambda t: (("s1", t[0] * t[1]), ("s2", t[0] * t[2]))
    )
    angles = st.tuples(ANGLE, ANGLE).map(lambda t: (("theta1", t[0]), ("theta2", t[1])))
    return st.one_of(
        warp("translate", P.translate, offset=VEC3),
        warp("shift3D", P.shift3D, dx=COORD, dy=COORD, dz=COORD),
        warp("scale", P.scale, factor=FACTOR),
        warp("scale3D", P.scale3D, sx=FACTOR, sy=FACTOR, sz=FACTOR),
        warp("stretch3D", P.stretch3D, x0=VEC3, sx=FACTOR, sy=FACTOR, sz=FACTOR),
        *(warp(n, getattr(P, n), theta=ANGLE) for n in ("rotate3DX", "rotate3DY", "rotate3DZ")),
        warp("rotate", P.rotate, angle=ANGLE, axis=DIRECTION),
        warp("orient", P.orient, direction=DIRECTION),
        *(ends(f"twist{a}", a.lower(), angles) for a in "XYZ"),
        *(ends(f"taper{a}", a.lower(), same_sign) for a in "XYZ"),
        warp("bend", P.bend, k=real(-0.5, 0.5)),
    )


def _trees(depth: int) -> st.SearchStrategy:
    if depth == 0:
        return LEAVES
    sub = _trees(depth - 1)
    return st.one_of(LEAVES, binary_ops(sub), binary_ops(sub), _unary_ops(sub), _warps(sub), _ternary_ops(sub))


_TREES = [_trees(d) for d in range(DEPTH + 1)]


@st.composite
def trees(draw, depth: int = DEPTH):
    """A random model: leaves of the catalogue under at most ``depth`` operations or transforms per path.

    (A composite, so that hypothesis names it ``trees()`` in its messages instead of spelling out
    the megabytes of nested ``one_of`` it is made of.)
    """
    return draw(_TREES[depth])


# ----------------------------------------------------------------------------- points

# values a random float rarely hits and the catalogue treats specially: centers, axes, planes
# of symmetry, the ends of twist/taper ranges (the parameters are drawn from the same floats)
_SPECIAL = st.sampled_from((0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 0.25, 2.0, -2.0))
COORDINATE = st.one_of(real(-POINT_BOX, POINT_BOX), _SPECIAL)


def points(n: int = 32) -> st.SearchStrategy[np.ndarray]:
    """(n, 3) float64 points in the box, with some coordinates on special values."""
    return hnp.arrays(np.float64, (n, 3), elements=COORDINATE)


# ----------------------------------------------------------------------------- creases

# multiples of 1/8 in [-1, 1]: products and sums of a few of them are exact in float32 and float64,
# so a primitive with such parameters is exactly 0 at the points listed below
DYADIC = st.integers(-8, 8).map(lambda k: k / 8)
POSITIVE_DYADIC = st.integers(1, 8).map(lambda k: k / 8)
DYADIC3 = st.tuples(DYADIC, DYADIC, DYADIC)


def _axis_points(c: tuple, r: float) -> list[tuple]:
    return [tuple(c[i] + s * r * (i == j) for i in range(3)) for j in range(3) for s in (1.0, -1.0)]


def _zero_sphere(name: str) -> st.SearchStrategy:
    fn = P.sphere if name == "sphere" else sdf.sphere
    return st.tuples(DYADIC3, POSITIVE_DYADIC).map(
        lambda t: (Leaf(name, fn, (("center", t[0]), ("r", t[1]))), _axis_points(t[0], t[1]))
    )


def _zero_block() -> st.SearchStrategy:
    def build(t):
        v, e = t
        # corners, edge midpoints and face centres (the block's own creases): v + e k / 2 with
        # k_i in {0, 1, 2}, not all 1 (the centre)
        pts = [tuple(v[i] + e[i] * k[i] / 2 for i in range(3)) for k in np.ndindex(3, 3, 3) if k != (1, 1, 1)]
        return Leaf("block", P.block, (("vertex", v), ("dx", e[0]), ("dy", e[1]), ("dz", e[2]))), pts

    return st.tuples(DYADIC3, st.tuples(POSITIVE_DYADIC, POSITIVE_DYADIC, POSITIVE_DYADIC)).map(build)


def _zero_torus() -> st.SearchStrategy:
    def build(t):
        c, big, small = t
        pts = [
            (c[0] + big + small, c[1], c[2]),
            (c[0] - big - small, c[1], c[2]),
            (c[0], c[1] + big, c[2] + small),
            (c[0], c[1] - big, c[2] - small),
        ]
        return Leaf("torusZ", P.torusZ, (("center", c), ("R", big), ("r", small))), pts

    return st.tuples(DYADIC3, POSITIVE_DYADIC, POSITIVE_DYADIC).map(build)


def _zero_cylinder(name: str) -> st.SearchStrategy:
    fn = P.cylZ if name == "cylZ" else sdf.cylinderZ
    return st.tuples(DYADIC3, POSITIVE_DYADIC, DYADIC).map(
        lambda t: (
            Leaf(name, fn, (("center", t[0]), ("r", t[1]))),
            [(t[0][0] + t[1], t[0][1], t[2]), (t[0][0], t[0][1] - t[1], t[2])],
        )
    )


def _zero_plane() -> st.SearchStrategy:
    def build(t):
        axis, p, u, v = t
        normal = tuple(float(i == axis) for i in range(3))
        pts = [tuple(p[i] if i == axis else (u if i == (axis + 1) % 3 else v) for i in range(3))]
        return Leaf("sdf.plane", sdf.plane, (("normal", normal), ("point", p))), pts + [p]

    return st.tuples(st.integers(0, 2), DYADIC3, DYADIC, DYADIC).map(build)


ZERO_LEAVES = st.one_of(
    _zero_sphere("sphere"),
    _zero_sphere("sdf.sphere"),
    _zero_block(),
    _zero_torus(),
    _zero_cylinder("cylZ"),
    _zero_cylinder("sdf.cylinderZ"),
    _zero_plane(),
)


def _touching_spheres() -> st.SearchStrategy:
    """Two balls of radius r touching at c + r e_i: both fields are exactly 0 there."""

    def build(t):
        c, r, axis, name = t
        fn = P.sphere if name == "sphere" else sdf.sphere
        c2 = tuple(c[i] + 2 * r * (i == axis) for i in range(3))
        touch = tuple(c[i] + r * (i == axis) for i in range(3))
        return Leaf(name, fn, (("center", c), ("r", r))), Leaf(name, fn, (("center", c2), ("r", r))), [touch]

    return st.tuples(DYADIC3, POSITIVE_DYADIC, st.integers(0, 2), st.sampled_from(("sphere", "sdf.sphere"))).map(build)


@st.composite
def creases(draw) -> tuple[object, np.ndarray, tuple]:
    """A tree with an operation whose two operands are both exactly 0, the (k, 3) points where they are,
    and ``(f1, f2, local)``: the operands and the points in their own coordinates (before the move).

    The operands are one primitive twice (every operation at f1 = f2 = 0; ``difference`` then
    meets f1 = -f2 = 0) or two balls touching at a point.  The operation may sit under another
    operation whose other operand is a random tree (the crease's value and gradient flow through
    it), and under a translation or a scaling by a power of two (exact, so the points still hit
    the crease).
    """
    if draw(st.booleans()):
        leaf, pts = draw(ZERO_LEAVES)
        f1, f2 = leaf, leaf
    else:
        f1, f2, pts = draw(_touching_spheres())
    tree = draw(binary_ops(st.just(f1), st.just(f2)))
    if draw(st.booleans()):  # the crease again as an operand: f1 = rho0 (tiny), f2 = 0
        tree = draw(binary_ops(st.just(tree), st.just(f1)))
    if draw(st.booleans()):  # under an operation with a random tree
        tree = draw(binary_ops(st.just(tree), trees(1)))
    pts = local = np.array(pts, dtype=np.float64)
    move = draw(st.sampled_from(("none", "translate", "scale")))
    if move == "translate":
        offset = draw(DYADIC3)
        tree = Warp("translate", P.translate, tree, (("offset", offset),))
        pts = pts + np.array(offset)
    elif move == "scale":
        factor = draw(st.sampled_from((0.5, 2.0, -2.0)))
        tree = Warp("scale", P.scale, tree, (("factor", factor),))
        pts = pts * factor
    return tree, pts, (f1, f2, local)
