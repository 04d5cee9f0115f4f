"""The models a user wrote in the app: one registry, read by every panel's model menu.

``register(model)`` keeps a model under its name (a new run of the same name replaces it);
:func:`workbench.app.paper_models` lists the registered models after the paper's, so a panel
built later offers them; :func:`offer` puts a model into a panel already built and opens it
there.  Panels keep their models in ``models`` (name -> Model) with a ``model_choice``
dropdown; the shape panel in ``choices`` with ``choice``.
"""

from __future__ import annotations

import threading
from typing import Any

from pyfrep_core import Model

__all__ = ["clear", "offer", "register", "user_models"]

_MODELS: dict[str, Model] = {}
_LOCK = threading.Lock()


def register(model: Model) -> str:
    """Keep ``model`` under its name for every panel's menu; returns the name.

    Examples
    --------
    >>> from pyfrep_core import Param, model, sphere
    >>> @model(bounds=((-1,) * 3, (1,) * 3), r=Param(0.5, 0.1, 0.9))
    ... def my_ball(x, r):
    ...     return sphere(x, r=r)
    >>> register(my_ball), list(user_models(dim=3))[-1]
    ('my_ball', 'my_ball')
    >>> clear()
    """
    if not isinstance(model, Model):
        raise TypeError(f"register: model must be a pyfrep_core Model (declared with @model), got {model!r}")
    with _LOCK:
        _MODELS.pop(model.__name__, None)  # a new run goes to the end: the newest model last
        _MODELS[model.__name__] = model
    return model.__name__


def user_models(dim: int | None = None) -> dict[str, Model]:
    """The registered models (name -> Model), oldest first, optionally of one dimension."""
    with _LOCK:
        return {k: m for k, m in _MODELS.items() if dim is None or m.dim == dim}


def clear() -> None:
    """Forget every registered model (tests)."""
    with _LOCK:
        _MODELS.clear()


def _menu(panel: Any) -> tuple[dict[str, Model] | None, Any]:
    if hasattr(panel, "model_choice") and isinstance(getattr(panel, "models", None), dict):
        return panel.models, panel.model_choice
    if hasattr(panel, "choice") and isinstance(getattr(panel, "choices", None), dict):
        return panel.choices, panel.choice
    return None, None


def offer(panel: Any, model: Model) -> bool:
    """Put ``model`` into ``panel``'s menu (first, as the newest) and open it there.

    A panel takes the model when it already offers a model of the same dimension (the slices
    take 2-D and 3-D, the others 3-D).  What a panel remembers by name from an earlier model
    of that name (a true distance, a trained network) is dropped.  Returns whether it took it.
    """
    models, choice = _menu(panel)
    if models is None or not any(getattr(m, "dim", 3) == model.dim for m in models.values()):
        return False
    name = model.__name__
    for cache in ("_distances", "networks", "trained"):  # results of the old model of this name
        held = getattr(panel, cache, None)
        if isinstance(held, dict):
            held.pop(name, None)
    was = choice.value
    models.pop(name, None)
    models[name] = model
    # the newest model first: setting the options selects the first, so one change opens it
    choice.options = [name, *[k for k in models if k != name]]
    if was == name:  # the same name run again: no value change, say it anyway
        choice.notify_change({"name": "value", "old": name, "new": name, "owner": choice, "type": "change"})
    return True
