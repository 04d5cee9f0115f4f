"""Meshing the Fig. 1 part over [-1.1, 1.1]^3 at 128^3 and 256^3: seconds, volume error, and sdfcad.

``polygonize`` = float32 grid evaluation (dense, or ``sparse=True``: exactly only in blocks
near the surface, the same mesh) + scikit-image marching cubes + every vertex moved onto
f = 0 in float64 + normals from grad f.  ``compiled``: the same, with the model evaluated
through ``pyfrep_core.compiled`` (torch.compile's fused kernels; their one-off compilation
time is printed apart).  Evaluation runs in chunks of 2^15 points on a pool
of single-threaded workers (torch's own 2-thread operations stall when a core is busy).
The peer is ``sdfcad`` (a PyPI fork of
fogleman/sdf) on the same shape written with its own operations, with the same voxel size,
in the same run: ``generate`` (threaded, sparse: it skips blocks that the distance bound
proves empty) returning a triangle soup.  Issue targets: at or below fogleman/sdf (about
1.5 s at 256^3 and 0.30 s at 128^3 on this kind of machine).

Times are the median of a few runs after a warm-up; on a machine shared with other jobs they
are noisy (torch's threads wait for each other when a core is taken), so polygonize is also
timed with one torch thread; the load average is printed with the figures.

Dual contouring (``polygonize(method="dc")``, issue 13): the Fig. 1 part at 128^3- and
256^3-equivalent voxel size (and 512^3, 1024^3 unless PYFREP_QUICK), a closed gyroid block and
the paper's microstructure, and ``fig1-minmax`` (the same part written with min and distances,
libfive's own field, so that both meshers mesh one function), each against marching cubes at
the same voxel size (``dc+compiled``: the model through ``compiled``, kernels compiled in the
warm-up): seconds,
triangles, volume error (closed forms: the Fig. 1 part; the gyroid solid over [-1, 1]^3 is half
the cube, 4, since f(-x) = -f(x)), pairs of self-intersecting faces (pymeshlab's candidates
confirmed by VTK's collision filter), and peak memory
(the child process's VmHWM less its resident size before meshing).

The peer named by the issue, libfive (octree dual contouring in C++), runs when ``LIBFIVE_LIB``
names its ``libfive.so`` (or the build folder): rows under each case up to 512^3 with the same
figures, from libfive's mesher through ctypes: ``lf`` on the same R-function field negated
(libfive's solid is f <= 0), ``lf-native`` (Fig. 1 part, gyroid) on the same solid written as
libfive's users do (max, Euclidean sphere and cylinders, max-norm cube: tighter intervals, fewer
operations, several times faster there); resolution (n - 1) / side voxels per unit, so its octree
has n cells along the shortest side where our grid has n - 1 (n = 128, 256); 2 worker threads
(``LIBFIVE_THREADS``) pinned to at most 2 CPUs, through the exported C++ entry that takes
libfive's settings (the C API's fixed 8 threads spin when idle); time: median, best and CPU
seconds (less sensitive to other jobs on the machine).  ``paired`` (Fig. 1 part and gyroid, up
to 256^3): ``dc+compiled`` and ``lf-native`` in one process, taking turns 2 runs + 1 times (which
goes first alternates), so that both meet the same phase of a machine whose speed drifts by a
third from hour to hour: their medians and the median of the rounds' ratios, with the least and
largest.  Each mesher then starts with the caches the other left (both are slower than alone).
Without it, a line says the peer was not run.  libfive is not on PyPI as a library; to build it
in a temporary folder (Debian)::

    apt-get install -y cmake g++ libeigen3-dev libboost-dev libpng-dev pkg-config
    git clone https://github.com/libfive/libfive /tmp/libfive_src
    cmake -S /tmp/libfive_src -B /tmp/libfive_build -DCMAKE_BUILD_TYPE=Release -DBUILD_STUDIO_APP=OFF \\
        -DBUILD_GUILE_BINDINGS=OFF -DBUILD_PYTHON_BINDINGS=OFF -DBUILD_TESTS=OFF -DENABLE_DEBUG=OFF
    make -C /tmp/libfive_build -j2 libfive
    LIBFIVE_LIB=/tmp/libfive_build/libfive/src/libfive.so .venv/bin/python benchmarks/mesh.py dc

Run: ``.venv/bin/python benchmarks/mesh.py [runs]`` (PYFREP_QUICK=1: 3 runs);
``benchmarks/mesh.py dc [runs]``: the dual-contouring table only.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import numpy as np
import torch
from skimage.measure import marching_cubes

from pyfrep_core import model, polygonize
from pyfrep_core._threads import intra_op_threads
from pyfrep_core.compiled import compiled, warm_up
from pyfrep_core.meshing.grid import _evaluate_grid, grid_axes
from pyfrep_core.meshing.roots import _project_vertices
from pyfrep_core.meshing.sparse import SPARSE_GUARD, SPARSE_STEP, _exact_neighbours, _sparse_grid
from pyfrep_core.models import fig1_part

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
BOUNDS = ((-1.1,) * 3, (1.1,) * 3)
EXACT_VOLUME = 0.9887887  # see tests/test_mesh.py
RESOLUTIONS = (128, 256)


def median_seconds(fn, runs: int) -> tuple[float, object]:
    out = fn()  # warm-up
    times = []
    for _ in range(runs):
        out = None  # the previous result freed first: the peak memory is one call's
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def sdfcad_shape():
    try:
        from sdf import X, Y, box, cylinder, sphere
    except ImportError:
        return None
    # the Fig. 1 program: sphere & cube, minus three infinite cylinders (z, x, y)
    return sphere(1) & box(1.5) - cylinder(0.5) - cylinder(0.5).orient(X) - cylinder(0.5).orient(Y)


def sdfcad_mesh(shape, resolution: int) -> np.ndarray:
    step = 2.2 / (resolution - 1)  # the same voxel size; sdf samples np.arange(lo, hi, step)
    bounds = ((-1.1,) * 3, (1.1 + step / 2,) * 3)
    return np.asarray(shape.generate(bounds=bounds, step=step, verbose=False)).reshape(-1, 3, 3)


def soup_volume(triangles: np.ndarray) -> float:
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def stages(resolution: int) -> dict[str, float]:
    """One run split into grid evaluation (dense and sparse), marching cubes and projection + grad f.

    On one intra-op thread, as polygonize runs them on the CPU.
    """
    with intra_op_threads(1):
        return _stages(resolution)


def _stages(resolution: int) -> dict[str, float]:
    axes = grid_axes(BOUNDS, resolution)
    t0 = time.perf_counter()
    _evaluate_grid(fig1_part, axes, torch.float32, "cpu", None)
    t1 = time.perf_counter()
    values, _, _, mask, evaluated = _sparse_grid(fig1_part, axes, torch.float32, "cpu", SPARSE_STEP, SPARSE_GUARD)
    t2 = time.perf_counter()
    index_verts, _, _, _ = marching_cubes(values, level=0.0, gradient_direction="descent", mask=mask)
    t3 = time.perf_counter()
    spacing = np.array([a[1] - a[0] for a in axes])
    _exact_neighbours(fig1_part, values, index_verts, evaluated, SPARSE_STEP, axes, torch.float32, "cpu")
    _project_vertices(fig1_part, values, index_verts, np.asarray(BOUNDS[0]), spacing, BOUNDS, "cpu")
    t4 = time.perf_counter()
    return {"dense grid": t1 - t0, "sparse grid": t2 - t1, "marching cubes": t3 - t2, "projection": t4 - t3}


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else (3 if QUICK else 5)
    shape = sdfcad_shape()
    print(
        f"meshing the Fig. 1 part over [-1.1, 1.1]^3, median of {runs} runs after a warm-up "
        f"({os.cpu_count()} CPUs, torch {torch.__version__} with {torch.get_num_threads()} threads, "
        f"load average {', '.join(f'{x:.2f}' for x in os.getloadavg())})"
    )
    fast_model = compiled(fig1_part)
    warm = warm_up(fast_model)
    for n in RESOLUTIONS:
        seconds, mesh = median_seconds(lambda n=n: polygonize(fig1_part, BOUNDS, n), runs)
        fast, sparse = median_seconds(lambda n=n: polygonize(fig1_part, BOUNDS, n, sparse=True), runs)
        same = np.array_equal(mesh.faces, sparse.faces) and np.abs(mesh.vertices - sparse.vertices).max() <= 1e-12
        err = mesh.volume() - EXACT_VOLUME
        split = ", ".join(f"{k} {v:.3f} s" for k, v in stages(n).items())
        print(f"  {n}^3  polygonize {seconds:6.3f} s  volume error {err:+.1e}  {mesh.n_faces} triangles  ({split})")
        print(
            f"         sparse=True {fast:6.3f} s  ({seconds / fast:.2f}x; {'the same' if same else 'a DIFFERENT'} mesh)"
        )
        fused, fused_mesh = median_seconds(lambda n=n: polygonize(fast_model, BOUNDS, n), runs)
        gap = (
            np.abs(fused_mesh.vertices - mesh.vertices).max()
            if np.array_equal(fused_mesh.faces, mesh.faces)
            else float("inf")
        )
        agree = f"same faces, vertices within {gap:.0e}" if np.isfinite(gap) else "OTHER faces"
        print(
            f"         compiled   {fused:6.3f} s  ({seconds / fused:.2f}x; compiled(fig1_part), kernels compiled "
            f"in {warm:.1f} s once; {agree})"
        )
        if shape is None:
            print("         sdfcad not installed: no peer figure")
            continue
        peer, soup = median_seconds(lambda n=n: sdfcad_mesh(shape, n), runs)
        peer_err = soup_volume(soup) - EXACT_VOLUME
        print(
            f"         sdfcad     {peer:6.3f} s  volume error {peer_err:+.1e}  {len(soup)} triangles  "
            f"-> sdfcad / polygonize = {peer / seconds:.2f}x (dense), {peer / fast:.2f}x (sparse), "
            f"{peer / fused:.2f}x (compiled)"
        )
    print(f"  load average after the runs: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


# ----------------------------------------------------------------------------- dual contouring


@model()
def gyroid_block(x: torch.Tensor) -> torch.Tensor:
    """The gyroid solid (paper's lattice, period 1) cut to [-1, 1]^3: exact volume 4."""
    from pyfrep_core import block, gyroid, intersection

    return intersection(gyroid(x), block(x, vertex=(-1.0, -1.0, -1.0), dx=2.0, dy=2.0, dz=2.0))


@model()
def fig1_minmax(x: torch.Tensor, r: float = 0.5) -> torch.Tensor:
    """The Fig. 1 part as libfive's users write it, in torch: min for intersection, Euclidean
    distances to sphere and cylinders, the max-norm for the cube (the same solid, another field)."""
    a, b, c = x[:, 0], x[:, 1], x[:, 2]
    out = torch.minimum(
        1.0 - torch.sqrt(a * a + b * b + c * c), 0.75 - torch.maximum(torch.maximum(a.abs(), b.abs()), c.abs())
    )
    for u, v in ((b, c), (a, c), (a, b)):
        out = torch.minimum(out, torch.sqrt(u * u + v * v) - r)
    return out


CASES = {
    "fig1": (lambda: fig1_part, BOUNDS, EXACT_VOLUME),
    "fig1-minmax": (lambda: fig1_minmax, BOUNDS, EXACT_VOLUME),
    "gyroid": (lambda: gyroid_block, BOUNDS, 4.0),
    "microstructure": (lambda: __import__("pyfrep_core.models", fromlist=["x"]).microstructure, None, None),
}


def _reset_peak() -> None:
    """Start VmHWM again from the resident size now (Linux), so that a warm-up's peak (compiling
    kernels) is not taken for the measured call's."""
    try:
        with open("/proc/self/clear_refs", "w") as refs:
            refs.write("5")
    except OSError:
        pass


def _resident_kib(key: str) -> int:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(key):
                return int(line.split()[1])
    return 0


def _child(case: str, method: str, n: int, runs: int) -> None:
    """Mesh once to warm up, then ``runs`` times; print seconds, triangles, volume, flagged faces, MiB."""
    import json

    from pyfrep_core.meshing.dual_contouring import dual_contour  # noqa: F401  (imported before measuring)

    make, bounds, _ = CASES[case]
    f = make()
    if method.endswith("+compiled"):  # the model through compiled kernels (compiled in the warm-up below)
        f, method = compiled(f), method.removesuffix("+compiled")
    polygonize(f, bounds, min(n, 64), method=method, progress=False)
    _reset_peak()
    before = _resident_kib("VmRSS")
    seconds, mesh = median_seconds(lambda: polygonize(f, bounds, n, method=method, progress=False), runs)
    peak = _resident_kib("VmHWM") - before
    # pairs of faces (no common vertex) that intersect: pymeshlab's candidates confirmed by VTK's collision
    # filter (tests/test_octree_dc.py; pymeshlab alone also flags coplanar neighbours that only touch)
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
    from test_octree_dc import self_intersecting_pairs

    flagged = len(self_intersecting_pairs(mesh))
    print(json.dumps([seconds, mesh.n_faces, mesh.volume(), flagged, peak / 1024]))


def measure(case: str, method: str, n: int, runs: int) -> tuple[float, int, float, int, float]:
    import json
    import subprocess

    out = subprocess.run(
        [sys.executable, __file__, "child", case, method, str(n), str(runs)], capture_output=True, text=True
    )
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return tuple(json.loads(out.stdout.strip().splitlines()[-1]))


# ----------------------------------------------------------------------------- libfive, the peer


def _libfive_library():
    """libfive's C library from ``LIBFIVE_LIB`` (libfive.so, or a folder holding it: the build or bindings
    folder), with the signatures used here; None when the variable is unset."""
    import ctypes
    import glob

    where = os.environ.get("LIBFIVE_LIB", "")
    if not where:
        return None
    path = where
    if os.path.isdir(where):
        # a build folder holds libfive/src/libfive.so; its bindings folder is libfive/bind/python
        found = [
            p
            for pattern in ("libfive.so", "src/libfive.so", "libfive/src/libfive.so", "../../src/libfive.so")
            for p in glob.glob(os.path.join(where, pattern))
        ]
        if not found:
            raise FileNotFoundError(f"LIBFIVE_LIB={where!r}: no libfive.so in that folder or its build tree")
        path = found[0]
    lib = ctypes.CDLL(os.path.abspath(path))

    class Interval(ctypes.Structure):
        _fields_ = [("lower", ctypes.c_float), ("upper", ctypes.c_float)]

    class Region(ctypes.Structure):
        _fields_ = [("X", Interval), ("Y", Interval), ("Z", Interval)]

    class Mesh(ctypes.Structure):
        _fields_ = [
            ("verts", ctypes.POINTER(ctypes.c_float)),  # (x, y, z) float triples
            ("tris", ctypes.POINTER(ctypes.c_uint32)),  # (a, b, c) index triples
            ("tri_count", ctypes.c_uint32),
            ("vert_count", ctypes.c_uint32),
        ]

    tree = ctypes.c_void_p
    for name, args, result in (
        ("libfive_tree_x", [], tree),
        ("libfive_tree_y", [], tree),
        ("libfive_tree_z", [], tree),
        ("libfive_tree_const", [ctypes.c_float], tree),
        ("libfive_tree_unary", [ctypes.c_int, tree], tree),
        ("libfive_tree_binary", [ctypes.c_int, tree, tree], tree),
        ("libfive_tree_delete", [tree], None),
        ("libfive_opcode_enum", [ctypes.c_char_p], ctypes.c_int),
        ("libfive_tree_render_mesh", [tree, Region, ctypes.c_float], ctypes.POINTER(Mesh)),
        ("libfive_tree_render_mesh_st", [tree, Region, ctypes.c_float], ctypes.POINTER(Mesh)),
        ("libfive_mesh_delete", [ctypes.POINTER(Mesh)], None),
    ):
        getattr(lib, name).argtypes = args
        getattr(lib, name).restype = result
    lib.Region, lib.Interval, lib.path = Region, Interval, path
    # The C API meshes with 8 worker threads (or 1): idle ones spin, so 8 on 2 busy cores measure the
    # contention.  libfive_tree_render_mesh_ (C++ linkage, exported) takes the settings themselves: a
    # BRepSettings laid out as libfive 2.x declares it (checked with offsetof: 56 bytes), or None.
    lib.with_settings = getattr(
        lib, "_Z25libfive_tree_render_mesh_PKN7libfive8TreeDataE15libfive_region3RKNS_12BRepSettingsE", None
    )
    if lib.with_settings is not None:

        class Settings(ctypes.Structure):
            _fields_ = [
                ("min_feature", ctypes.c_double),
                ("max_err", ctypes.c_double),  # 1e-8, libfive's default: merge only near-linear cells
                ("workers", ctypes.c_uint),
                ("alg", ctypes.c_int),  # 0: dual contouring
                ("free_thread_handler", ctypes.c_void_p),
                ("progress_handler", ctypes.c_void_p),
                ("vol", ctypes.c_void_p),
                ("cancel", ctypes.c_bool),
            ]

        assert ctypes.sizeof(Settings) == 56
        lib.with_settings.argtypes = [tree, Region, ctypes.POINTER(Settings)]
        lib.with_settings.restype = ctypes.POINTER(Mesh)
        lib.Settings = Settings
    return lib


class _Five:
    """A libfive expression (a C handle, freed with the object) with the arithmetic the models need."""

    lib = None

    def __init__(self, ptr):
        if not ptr:
            raise RuntimeError("libfive returned no tree")
        self.ptr = ptr

    def __del__(self):
        self.lib.libfive_tree_delete(self.ptr)

    @classmethod
    def wrap(cls, value) -> _Five:
        return value if isinstance(value, _Five) else cls(cls.lib.libfive_tree_const(float(value)))

    def _op(self, name: str, *others) -> _Five:
        code = self.lib.libfive_opcode_enum(name.encode())
        if not others:
            return _Five(self.lib.libfive_tree_unary(code, self.ptr))
        other = _Five.wrap(others[0])  # held until the call returns: its handle is freed with it
        return _Five(self.lib.libfive_tree_binary(code, self.ptr, other.ptr))

    def __add__(self, other):
        return self._op("add", other)

    def __radd__(self, other):
        return _Five.wrap(other)._op("add", self)

    def __sub__(self, other):
        return self._op("sub", other)

    def __rsub__(self, other):
        return _Five.wrap(other)._op("sub", self)

    def __mul__(self, other):
        return self._op("mul", other)

    def __rmul__(self, other):
        return _Five.wrap(other)._op("mul", self)

    def __truediv__(self, other):
        return self._op("div", other)

    def __rtruediv__(self, other):
        return _Five.wrap(other)._op("div", self)

    def __neg__(self):
        return self._op("neg")

    def square(self):
        return self._op("square")

    def sqrt(self):
        return self._op("sqrt")

    def sin(self):
        return self._op("sin")

    def cos(self):
        return self._op("cos")


# The benchmark's models written again with libfive's operations: the same R-functions (operations.py)
# and primitives (primitives.py, lattices.py, models/), so the same field, negated (libfive: f <= 0 inside).
def _r_and(a, b):
    return a + b - (a.square() + b.square()).sqrt()


def _r_or(a, b):
    return a + b + (a.square() + b.square()).sqrt()


def _five_block(x, y, z, lo: float, size: float):
    sx, sy, sz = ((t - lo) * (size - (t - lo)) for t in (x, y, z))
    return _r_and(_r_and(sx, sy), sz)


def _five_fig1(x, y, z, r: float = 0.5):
    t1 = _r_and(1.0 - (x.square() + y.square() + z.square()), _five_block(x, y, z, -0.75, 1.5))
    for cylinder in (r * r - y.square() - z.square(), r * r - x.square() - z.square(), r * r - x.square() - y.square()):
        t1 = _r_and(t1, -cylinder)
    return t1


def _five_gyroid_block(x, y, z):
    X, Y, Z = (2.0 * np.pi * t for t in (x, y, z))
    g = -(X.sin() * Y.cos() + Y.sin() * Z.cos() + Z.sin() * X.cos())
    return _r_and(g, _five_block(x, y, z, -1.0, 2.0))


def _five_microstructure(x, y, z, scale1=9.0, scale2=3.0, freq1=0.75, freq2=0.85, radius=10.0, shell=0.15):
    sp = 1.0 - (x.square() + y.square() + z.square()) / (radius * radius)
    skin = _r_and(sp, -(sp - shell))
    scale = scale1 * (1.0 - sp) + scale2 * sp
    c = freq1 * (1.0 - sp) + freq2 * sp
    xs, ys, zs = ((t * scale).sin() - c for t in (x, y, z))
    xrods, yrods, zrods = _r_and(ys, zs), _r_and(xs, zs), _r_and(xs, ys)
    blend = _r_or(xrods, zrods) + 1.0 / (1.0 + (xrods / 3.0).square() + (zrods / 3.0).square())  # blendUnion
    grid = _r_or(blend, yrods)
    return _r_and(_r_or(skin, _r_and(sp, grid)), y)


# The same solids as libfive's users write them (its own ground): max for intersection, Euclidean
# distances for sphere and cylinders, the max-norm for the cube, already f <= 0 inside.
def _five_max(*fs):
    out = fs[0]
    for f in fs[1:]:
        out = out._op("max", f)
    return out


def _five_cube(x, y, z, half: float):
    return _five_max(x._op("abs"), y._op("abs"), z._op("abs")) - half


def _five_fig1_native(x, y, z, r: float = 0.5):
    ball = (x.square() + y.square() + z.square()).sqrt() - 1.0
    holes = ((u.square() + v.square()).sqrt() - r for u, v in ((y, z), (x, z), (x, y)))
    return _five_max(ball, _five_cube(x, y, z, 0.75), *(-h for h in holes))


def _five_gyroid_native(x, y, z):
    X, Y, Z = (2.0 * np.pi * t for t in (x, y, z))
    return _five_max(X.sin() * Y.cos() + Y.sin() * Z.cos() + Z.sin() * X.cos(), _five_cube(x, y, z, 1.0))


# case -> variant -> tree builder; "field" trees are negated when meshed, "native" ones are not
LIBFIVE_MODELS = {
    "fig1": {"field": _five_fig1, "native": _five_fig1_native},
    "fig1-minmax": {"field": lambda x, y, z: -_five_fig1_native(x, y, z)},  # negated back: libfive's own field
    "gyroid": {"field": _five_gyroid_block, "native": _five_gyroid_native},
    "microstructure": {"field": _five_microstructure},  # the graded blend has no min/max form
}
LIBFIVE_THREADS = int(os.environ.get("LIBFIVE_THREADS", "2"))


def _libfive_mesher(case: str, n: int, variant: str = "field"):
    """libfive's mesher of a case at the voxel size of an n^3 grid, as a function that meshes once and
    returns (vertices, triangles); ``LIBFIVE_THREADS`` worker threads, this process on at most 2 CPUs."""
    import ctypes

    lib = _libfive_library()
    _Five.lib = lib
    cpus = sorted(os.sched_getaffinity(0))[:2]
    os.sched_setaffinity(0, cpus)
    _, bounds, _ = CASES[case]
    if bounds is None:
        bounds = CASES[case][0]().bounds
    lo, hi = np.asarray(bounds, dtype=np.float64)
    region = lib.Region(*(lib.Interval(a, b) for a, b in zip(lo, hi)))
    # libfive halves every side of the region until the shortest is below 1 / resolution: with
    # (n - 1) / side voxels per unit, 2^ceil(log2(n - 1)) cells along it (n = 128, 256: n cells, ours n - 1)
    resolution = (n - 1) / float((hi - lo).min())
    shape = LIBFIVE_MODELS[case][variant](
        *(_Five(lib.libfive_tree_x()), _Five(lib.libfive_tree_y()), _Five(lib.libfive_tree_z()))
    )
    if variant == "field":
        shape = -shape
    threads = LIBFIVE_THREADS
    if lib.with_settings is not None:
        settings = lib.Settings(1.0 / resolution, 1e-8, threads, 0, None, None, None, False)

        def render(tree, region, resolution):
            return lib.with_settings(tree, region, ctypes.byref(settings))

    else:
        render = lib.libfive_tree_render_mesh if threads != 1 else lib.libfive_tree_render_mesh_st

    def mesh_once():
        out = render(shape.ptr, region, resolution)
        if not out:
            raise RuntimeError(f"libfive returned no mesh for {case} at {n}^3")
        m = out.contents
        verts = np.ctypeslib.as_array(m.verts, shape=(m.vert_count * 3,)).reshape(-1, 3).astype(np.float64)
        tris = np.ctypeslib.as_array(m.tris, shape=(m.tri_count * 3,)).reshape(-1, 3).astype(np.int64)
        lib.libfive_mesh_delete(out)
        return verts, tris

    return mesh_once


def _libfive_child(case: str, n: int, runs: int, variant: str = "field") -> None:
    """libfive's mesh of a case at the voxel size of an n^3 grid: seconds (median and best), triangles,
    volume, flagged faces, MiB, CPU seconds (median)."""
    import json

    from pyfrep_core.meshing import Mesh

    mesh_once = _libfive_mesher(case, n, variant)
    out = mesh_once()  # warm-up
    del out
    _reset_peak()
    before = _resident_kib("VmRSS")
    times, cpu = [], []
    for _ in range(runs):
        c0, t0 = time.process_time(), time.perf_counter()
        out = mesh_once()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)  # all threads: idle workers spin, so this counts them too
    peak = _resident_kib("VmHWM") - before
    mesh = Mesh(*out)
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
    from test_octree_dc import self_intersecting_pairs

    flagged = len(self_intersecting_pairs(mesh))
    figures = [statistics.median(times), min(times), mesh.n_faces, mesh.volume(), flagged, peak / 1024]
    print(json.dumps([*figures, statistics.median(cpu)]))


def _paired_child(case: str, method: str, n: int, rounds: int, variant: str) -> None:
    """Our mesher and libfive's in one process, taking turns ``rounds`` times (which goes first
    alternates): their median seconds, and the median, least and largest of the rounds' ratios."""
    import json

    make, bounds, _ = CASES[case]
    f = make()
    if method.endswith("+compiled"):
        f, method = compiled(f), method.removesuffix("+compiled")
    mesh_once = _libfive_mesher(case, n, variant)  # this process on at most 2 CPUs, as libfive's child

    def ours():
        return polygonize(f, bounds, n, method=method, progress=False)

    for warm in (ours, mesh_once):
        warm()
    times: dict = {ours: [], mesh_once: []}
    for k in range(rounds):
        for fn in (ours, mesh_once) if k % 2 == 0 else (mesh_once, ours):
            t0 = time.perf_counter()
            out = fn()
            times[fn].append(time.perf_counter() - t0)
            del out
    ratios = [a / b for a, b in zip(times[ours], times[mesh_once])]
    medians = [statistics.median(times[ours]), statistics.median(times[mesh_once])]
    print(json.dumps([*medians, statistics.median(ratios), min(ratios), max(ratios)]))


def paired_row(case: str, method: str, n: int, rounds: int) -> str:
    """The paired line of a case (``lf-native`` where written, else ``lf``; see :func:`_paired_child`)."""
    import json
    import subprocess

    variant = "native" if "native" in LIBFIVE_MODELS[case] else "field"
    label = "lf" if variant == "field" else f"lf-{variant}"
    command = [sys.executable, __file__, "paired-child", case, method, str(n), str(rounds), variant]
    out = subprocess.run(command, capture_output=True, text=True)
    if out.returncode:
        why = out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"exit status {out.returncode}"
        return f"paired run failed: {why}"
    ours, theirs, ratio, least, most = json.loads(out.stdout.strip().splitlines()[-1])
    return (
        f"paired (one process, {rounds} rounds taking turns): {method} {ours:.3f} s, {label} {theirs:.3f} s; "
        f"{method} / {label} = {ratio:.2f}x (rounds {least:.2f}x-{most:.2f}x)"
    )


def libfive_note() -> bool:
    """Print whether the libfive peer runs (and from where); True when it does."""
    try:
        lib = _libfive_library()
    except OSError as error:
        print(f"  libfive: LIBFIVE_LIB could not be loaded ({error}); peer not run")
        return False
    if lib is None:
        print(
            "  libfive: peer not run (set LIBFIVE_LIB to a libfive.so built as in this file's docstring "
            "to get its figures in the same run)"
        )
        return False
    if lib.with_settings is not None:
        threads = f"{LIBFIVE_THREADS} worker thread(s)"
    else:
        threads = "1 thread" if LIBFIVE_THREADS == 1 else "the C API's 8 worker threads"
    print(
        f"  libfive: {lib.path}, libfive_tree_render_mesh ({threads} on at most 2 CPUs); lf: the same "
        "R-function fields negated, lf-native: max and distances"
    )
    return True


def libfive_row(case: str, n: int, runs: int, ours: dict[str, float]) -> str:
    """libfive's lines for a case (``lf``: our field negated, ``lf-native``: min/max and distances where
    written), with our median seconds over libfive's median for each of our methods measured."""
    import json
    import subprocess

    lines = []
    for variant in LIBFIVE_MODELS[case]:
        label = "lf" if variant == "field" else f"lf-{variant}"
        command = [sys.executable, __file__, "libfive-child", case, str(n), str(runs), variant]
        out = subprocess.run(command, capture_output=True, text=True)
        if out.returncode:
            why = out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"exit status {out.returncode}"
            lines.append(f"{label} failed: {why}")
            continue
        seconds, best, faces, volume, flagged, mib, cpu = json.loads(out.stdout.strip().splitlines()[-1])
        exact = CASES[case][2]
        err = f"volume error {volume - exact:+.1e}" if exact is not None else f"volume {volume:.4f}"
        ratios = ", ".join(f"{m} / {label} = {s / seconds:.2f}x" for m, s in ours.items())
        lines.append(
            f"{label} {seconds:7.3f} s {faces:9d} triangles {err} self-intersecting pairs {flagged} {mib:6.0f} MiB"
            f"  (best {best:.3f} s, CPU {cpu:.3f} s; {ratios})"
        )
    return "\n                         ".join(lines)


def dual_contouring_table(runs: int) -> None:
    print(
        "dual contouring (octree, certified pruning) against marching cubes at the same voxel size "
        f"(median of {runs} runs, each case in its own process; load average "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())})"
    )
    peer = libfive_note()
    rows = [("fig1", 128), ("fig1", 256), ("fig1-minmax", 128), ("fig1-minmax", 256), ("gyroid", 128)]
    rows += [("microstructure", 128)]
    if not QUICK:
        rows += [("fig1", 512), ("fig1", 1024)]
    for case, n in rows:
        exact = CASES[case][2]
        line = []
        figures = {}
        for method in ("mc", "dc", "dc+compiled"):
            if method == "mc" and n > 512:
                line.append("mc: skipped (dense grid)")
                continue
            reps = runs if n <= 256 else 1
            seconds, faces, volume, flagged, mib = measure(case, method, n, reps)
            figures[method] = seconds
            err = f"volume error {volume - exact:+.1e}" if exact is not None else f"volume {volume:.4f}"
            line.append(
                f"{method} {seconds:7.3f} s {faces:9d} triangles {err} self-intersecting pairs {flagged} {mib:6.0f} MiB"
            )
        ratio = f"  mc / dc = {figures['mc'] / figures['dc']:.2f}x" if {"mc", "dc"} <= figures.keys() else ""
        print(f"  {case:>14} {n:4d}^3  " + "\n                         ".join(line) + ratio)
        if peer and n <= 512:
            print("                         " + libfive_row(case, n, runs if n <= 256 else 1, figures))
        if peer and n <= 256 and case in ("fig1", "gyroid"):
            print("                         " + paired_row(case, "dc+compiled", n, 2 * runs + 1))
    print(f"  load average after the runs: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "child":
        _child(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]))
    elif len(sys.argv) > 1 and sys.argv[1] == "libfive-child":
        _libfive_child(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), *sys.argv[5:])
    elif len(sys.argv) > 1 and sys.argv[1] == "paired-child":
        _paired_child(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), sys.argv[6])
    elif len(sys.argv) > 1 and sys.argv[1] == "dc":
        dual_contouring_table(int(sys.argv[2]) if len(sys.argv) > 2 else (3 if QUICK else 5))
    else:
        main()
        dual_contouring_table(int(sys.argv[1]) if len(sys.argv) > 1 else (3 if QUICK else 5))
