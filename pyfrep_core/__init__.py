"""pyfrep_core: the differentiable Function Representation kernel.

A solid is a function f: R^3 -> R, f >= 0 inside, written with torch so autograd gives
derivatives with respect to points and shape parameters.

>>> import torch
>>> from pyfrep_core import *
>>> def model(x):
...     sp1 = sphere(x, center=(0, 0, 0), r=1)
...     b1 = block(x, vertex=(-0.75, -0.75, -0.75), dx=1.5, dy=1.5, dz=1.5)
...     t1 = intersection(sp1, b1)
...     c1 = cylX(x, center=(0, 0, 0), r=0.5)
...     c2 = cylY(x, center=(0, 0, 0), r=0.5)
...     c3 = cylZ(x, center=(0, 0, 0), r=0.5)
...     t2 = difference(t1, c1)
...     t3 = difference(t2, c2)
...     t4 = difference(t3, c3)
...     return t4
>>> model(torch.tensor([[0.55, 0.55, 0.55], [0.0, 0.0, 0.0]])) > 0
tensor([ True, False])
"""

from . import sdf
from .convolution import *  # noqa: F403
from .convolution import __all__ as _convolution_all
from .curvature import Curvatures, attach_curvatures, curvatures, gaussian_curvature, mean_curvature
from .diff import div, grad, hessian, laplacian, p_laplacian, param_grad, project_to_surface, value_and_grad
from .distance import distance_error, fmm_distance, surface_distance, true_distance
from .field_io import save_field
from .fitting import FitResult, IdentifiabilityWarning, fit
from .freeform import FreeformModel, fit_freeform
from .interval import IntervalUnsupported, bounds
from .io import load_mesh, load_points, save_mesh, save_points
from .lattices import *  # noqa: F403
from .lattices import __all__ as _lattices_all
from .meshing import Mesh, polygonize
from .model import Model, Param, model
from .normalization import delta_1, normalized, omega_1, omega_k
from .operations import *  # noqa: F403
from .operations import __all__ as _operations_all
from .periodic import *  # noqa: F403
from .periodic import __all__ as _periodic_all
from .pose import initial_pose, posed
from .primitives import *  # noqa: F403
from .primitives import __all__ as _primitives_all
from .progress import Event, Progress
from .redistancing import RedistancedSDF, load_redistanced, redistance
from .sampling import sample_surface
from .sensitivity import normal_velocity
from .transforms import *  # noqa: F403
from .transforms import __all__ as _transforms_all

__version__ = "0.1.0"
__all__ = [
    "Curvatures",
    "Event",
    "FitResult",
    "IdentifiabilityWarning",
    "FreeformModel",
    "IntervalUnsupported",
    "Mesh",
    "Model",
    "Param",
    "Progress",
    "RedistancedSDF",
    "attach_curvatures",
    "bounds",
    "curvatures",
    "delta_1",
    "distance_error",
    "div",
    "fit",
    "initial_pose",
    "fit_freeform",
    "fmm_distance",
    "gaussian_curvature",
    "grad",
    "hessian",
    "laplacian",
    "load_mesh",
    "load_redistanced",
    "load_points",
    "mean_curvature",
    "model",
    "normal_velocity",
    "normalized",
    "omega_1",
    "omega_k",
    "p_laplacian",
    "param_grad",
    "polygonize",
    "posed",
    "project_to_surface",
    "redistance",
    "sample_surface",
    "save_field",
    "save_mesh",
    "save_points",
    "sdf",
    "surface_distance",
    "true_distance",
    "value_and_grad",
    *_convolution_all,
    *_lattices_all,
    *_operations_all,
    *_periodic_all,
    *_primitives_all,
    *_transforms_all,
]
