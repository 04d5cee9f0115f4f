"""Free-form fits against screened Poisson reconstruction, from the same clouds, in the same run.

For a sphere, a torus and the Fig. 1 part: 20k points sampled on the surface
(:func:`pyfrep_core.sample_surface`) with outward normals (-grad f / |grad f|), Gaussian noise
of 0.2 % of the size on every coordinate (as tests/test_freeform.py).  Reconstructions:

* ``fit_freeform`` with the tests' quick settings (3 x 64, a few hundred steps) and with its
  defaults (4 x 128, 1500 steps);
* screened Poisson reconstruction (Kazhdan & Hoppe 2013) by MeshLab's filter through
  ``pymeshlab`` (``generate_surface_reconstruction_screened_poisson``, octree depth 8), when
  ``pymeshlab`` is installed (it is not a dependency of the library:
  ``pip install pymeshlab``); otherwise the baseline is reported as missing.

Each is measured the same way, as a triangle mesh (the free-form model polygonized at 128^3):
the mean and max of the distances from 20k area-uniform points of the reconstruction to the
true surface (:func:`pyfrep_core.true_distance`, exact to the projection tolerance) and from
20k points of the true surface to the mesh (VTK's ``vtkImplicitPolyDataDistance``, exact for a
mesh); Chamfer = the mean of the two means, Hausdorff = the largest distance.  The free-form
model's own zero set is also measured with :func:`pyfrep_core.surface_distance`.  All in % of
the size (the cloud's largest extent).  Times are wall seconds on this machine, printed with the
load average; the ratio is free-form time / Poisson time.

    .venv/bin/python benchmarks/freeform.py [--shapes sphere,torus,fig1_part] [--settings quick,default]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from pyfrep_core import fit_freeform, grad, polygonize, sample_surface, sphere, surface_distance, torusZ, true_distance
from pyfrep_core.models import fig1_part
from pyfrep_core.sampling import sample_mesh

N_POINTS = 20_000
NOISE = 0.002
SETTINGS = {
    "quick": {"width": 64, "depth": 3, "batch": 512, "steps": 400},
    "default": {},
}
SHAPES = {
    "sphere": (lambda x: sphere(x, r=1.0), ((-1.3,) * 3, (1.3,) * 3)),
    "torus": (lambda x: torusZ(x, R=1.0, r=0.35), ((-1.5, -1.5, -0.5), (1.5, 1.5, 0.5))),
    "fig1_part": (lambda x: fig1_part(x), fig1_part.bounds),
}


def oriented_cloud(f, bounds, seed=0):
    pts = sample_surface(f, N_POINTS, seed=seed, bounds=bounds, resolution=96)
    g = grad(f, pts)
    normals = -g / np.linalg.norm(g, axis=1, keepdims=True)
    size = float((pts.max(0) - pts.min(0)).max())
    return pts + np.random.default_rng(seed + 1).normal(0.0, NOISE * size, pts.shape), normals, size


def poisson(points, normals, depth=8):
    """Screened Poisson reconstruction with pymeshlab: (vertices, faces), or None without pymeshlab."""
    try:
        import pymeshlab
    except ImportError:
        return None
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points, v_normals_matrix=normals))
    ms.generate_surface_reconstruction_screened_poisson(depth=depth, preclean=True)
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


def mesh_errors(vertices, faces, truth, on_truth, seed=0):
    """(chamfer, hausdorff) of a triangle mesh against the true surface (module docstring)."""
    import pyvista as pv

    from pyfrep_core import Mesh

    on_mesh = sample_mesh(Mesh(vertices, faces), N_POINTS, np.random.default_rng(seed))
    to_truth = truth.unsigned(on_mesh)
    surface = pv.PolyData.from_regular_faces(vertices, faces)
    to_mesh = np.abs(pv.PolyData(on_truth).compute_implicit_distance(surface)["implicit_distance"])
    return 0.5 * (to_truth.mean() + to_mesh.mean()), max(to_truth.max(), to_mesh.max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", default=",".join(SHAPES))
    parser.add_argument("--settings", default=",".join(SETTINGS))
    args = parser.parse_args()
    print(f"torch threads {torch.get_num_threads()} (fit_freeform trains on one); load average {os.getloadavg()}")
    print(f"{'shape':10} {'method':22} {'seconds':>8} {'chamfer %':>10} {'hausdorff %':>12} {'own zero set':>22}")
    for name in args.shapes.split(","):
        f, bounds = SHAPES[name]
        pts, normals, size = oriented_cloud(f, bounds)
        truth = true_distance(f, bounds, resolution=96)
        on_truth = sample_surface(f, N_POINTS, seed=7, bounds=bounds, resolution=96)
        start = time.perf_counter()
        rec = poisson(pts, normals)
        t_poisson = time.perf_counter() - start
        if rec is None:
            print(f"{name:10} {'screened Poisson':22} {'pymeshlab not installed: no baseline':>60}")
        else:
            ch, hd = mesh_errors(*rec, truth, on_truth)
            print(
                f"{name:10} {'screened Poisson d8':22} {t_poisson:8.2f} {100 * ch / size:10.3f} {100 * hd / size:12.3f}"
            )
        for setting in args.settings.split(","):
            start = time.perf_counter()
            model = fit_freeform(pts, normals, progress=False, seed=0, **SETTINGS[setting])
            seconds = time.perf_counter() - start
            mesh = polygonize(model, resolution=128, progress=False)
            ch, hd = mesh_errors(mesh.vertices, mesh.faces, truth, on_truth)
            own = surface_distance(f, model, bounds, n_points=N_POINTS // 4, resolution=96)
            ratio = f" (time {seconds / t_poisson:.2f} x Poisson's)" if rec is not None else ""
            print(
                f"{name:10} {'fit_freeform ' + setting:22} {seconds:8.2f} {100 * ch / size:10.3f} "
                f"{100 * hd / size:12.3f} {100 * own.chamfer / size:10.3f} / {100 * own.hausdorff / size:.3f}{ratio}",
                flush=True,
            )
    print(f"load average at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()
