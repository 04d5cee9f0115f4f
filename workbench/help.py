"""What am I looking at? a short text at the top of each tab, with the paper's equation or figure.

Numbers are those of the paper (Fayolle et al., differentiable F-Rep with PyFRep): equations
(2) fitting loss, (3) mean curvature, (4) Gaussian curvature, (5) omega_1, (6) omega_k,
(8) delta_1, (9) eikonal loss, (10) E(p); figures 1-2 the program and its radius, 5 Schwarz D,
6 the ellipse's normalizations, 7-8 the pawn and its distance, 9-10 the fitted microstructure.
"""

from __future__ import annotations

import ipywidgets as widgets

__all__ = ["HELP", "help_box"]

HELP: dict[str, str] = {
    "Shape": (
        "The solid is the set f(x; p) &ge; 0 of a model written as a program (paper Fig. 1); the surface f = 0 is "
        "re-meshed as you move a parameter p (Fig. 2: the cylinder radius r at 0.35, 0.5, 0.65). "
        "Colour: the <i>normal velocity</i> v = &minus;(&part;f/&part;p)/|&nabla;f|, how fast each surface point "
        "moves along its normal per unit of p (red: into the solid, blue: outward, white: not at all), from the "
        "automatic derivative of f with respect to p (section 4). <i>section</i> cuts the view with a plane. "
        "<i>push-pull</i>: click a point of the surface and type or drag how far it moves along its normal (or "
        "turn on <i>drag the surface</i> and drag the point itself); the parameters that move it there are solved "
        "for with the same normal velocities, least squares within their ranges."
    ),
    "Curvature": (
        "Curvatures of the surface f = 0 at the mesh vertices, from the automatic first and second derivatives "
        "of f (paper section 5.1): mean curvature H = &minus;&frac12; div(&nabla;f/|&nabla;f|) (eq. 3), Gaussian "
        "curvature K = &nabla;f Hessian*(f) &nabla;f<sup>T</sup>/|&nabla;f|<sup>4</sup> (eq. 4), principal "
        "curvatures k = H &plusmn; &radic;(H&sup2; &minus; K). On Schwarz D, a minimal surface, H = 0 and K &le; 0 "
        "(Fig. 5). Grey: no curvature there (&nabla;f = 0, or a crease where f is not twice differentiable)."
    ),
    "Slices": (
        "A plane through the model: f and three approximations of the distance to f = 0 built from f and its "
        "derivatives (paper section 5.2): &omega;<sub>1</sub> = f/&radic;(f&sup2; + |&nabla;f|&sup2;) (eq. 5), "
        "&omega;<sub>2</sub> (eq. 6), &delta;<sub>1</sub> = f/|&nabla;f| (eq. 8), the trained network of the "
        "Redistancing tab and the true distance d; below each, |field &minus; d|. The ellipse with semi-axes 5 "
        "and 2 is Fig. 6. Bold black: the zero level, the surface."
    ),
    "Redistancing": (
        "Training a network h so that d(x) = sign(f(x)) h(x) is the signed distance to f = 0 (paper section 5.3): "
        "the loss is the eikonal residual E(|&nabla;d| &minus; 1)&sup2; over the box (eq. 9); the default "
        "also fits distances sampled near the surface (labels), the paper's mode (menu <i>training</i>) uses "
        "only f. The sign of f keeps the surface exactly where it is. The slices compare f and d with the "
        "true distance (the pawn: Figs. 7 and 8). Stop ends the training early."
    ),
    "Fitting": (
        "Recovering a model's parameters p from points x<sub>i</sub> measured on a surface (section 5.4). The "
        "paper's loss is algebraic, E(p) = (1/N) &Sigma; f(x<sub>i</sub>; p)&sup2; (eq. 10); the <i>geometric</i> "
        "residual f/|&nabla;f| (&delta;<sub>1</sub>, eq. 8) is a length, independent of how f is scaled. "
        "Regularized evolution finds a start, gradient descent and a least-squares polish with &part;f/&part;p from "
        "automatic differentiation refine it; <i>pose</i> adds a rigid move (and scale) of the points, "
        "<i>loss</i> a robust weighting that sets stray points (red) apart. Points are coloured by their residual "
        "(Fig. 9 for the microstructure); the table gives each parameter &plusmn; its standard error."
    ),
}


def help_box(title: str) -> widgets.HTML:
    """The tab's help text (empty for a tab without one).

    Examples
    --------
    >>> "eq. 3" in help_box("Curvature").value
    True
    """
    text = HELP.get(title, "")
    return widgets.HTML(
        f"<div class='pyfrep-help' style='font-size:13px;line-height:1.35;max-width:1100px;color:#333'>"
        f"<b>What am I looking at?</b> {text}</div>"
        if text
        else "",
        layout=widgets.Layout(margin="0 0 6px 0"),
    )
