"""Model panel: write an ``@model`` in a code editor, Run, and it opens in every panel with its sliders.

Run works like a notebook cell: the code is compiled and executed in the kernel's own namespace
(the user's, where ``workbench.app()`` was called), so what it defines stays there.  The last
``Model`` the code defines (``@model(...)`` on a function) is checked on a coarse grid of its
bounds (f is called as every panel will call it), shown beside the editor with one slider per
``Param``, registered for every panel's model menu and opened in the panels already built
(the app's :meth:`~workbench.app.App.open_model`).  An error shows its line in the code: a
SyntaxError where Python found it, a runtime error (when the code runs or when f is called)
with the traceback cut to the lines of the user's code.
"""

from __future__ import annotations

import ast
import html
import linecache
import time
import traceback
from collections.abc import Callable
from typing import Any

import ipywidgets as widgets
import torch

from pyfrep_core import Model

from .code_editor import CodeEditor
from .model_templates import TEMPLATES
from .user_models import register

__all__ = ["ModelPanel", "check_model", "model_panel"]

SOURCE = "<model editor"  # the file name of every run's code starts so: its frames are the user's

HELP = (
    "<details style='font-size:13px;line-height:1.35'><summary><b>What am I looking at?</b></summary>"
    "A model is a Python function <code>f(x, **params)</code> on torch tensors: <code>x</code> is an (N, 3) "
    "array of points, the result (N,) values with <b>f &ge; 0 inside</b> the solid and f = 0 on its surface "
    "(the paper's section 2). <code>@model(bounds=..., name=Param(default, lower, upper, label=...))</code> "
    "declares its parameters: each becomes a slider, a fitting unknown and a push-pull unknown (section 4). "
    "<b>Run</b> executes the code in this kernel, like a notebook cell, and opens the last model it defines "
    "here and in every tab. Build shapes from the catalogue (<code>sphere</code>, <code>block</code>, "
    "<code>cylX</code>, <code>gyroid</code>, ...) with the R-functions <code>union</code>, "
    "<code>intersection</code>, <code>difference</code>, or write the formula yourself with "
    "<code>p[:, 0]</code>, <code>p[:, 1]</code>, <code>p[:, 2]</code>. Tab and Shift-Tab indent and "
    "dedent (4 spaces, the selected lines)."
    "</details>"
)


def _defined_names(tree: ast.Module) -> list[str]:
    """Names bound at the top level of the code, in the order of their lines."""
    names: list[tuple[int, str]] = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.append((node.lineno, node.name))
        elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for sub in ast.walk(target):
                    if isinstance(sub, ast.Name):
                        names.append((node.lineno, sub.id))
    return [name for _, name in sorted(names)]


def user_traceback(err: BaseException) -> tuple[str, int | None]:
    """The error as the user's code sees it: the frames of the editor's code only, and the line (1-based)
    of the innermost one (None when the error arose outside the user's code).

    Examples
    --------
    >>> code = "def f(x):\\n    return 1 / x\\n\\nf(0)\\n"
    >>> try:
    ...     exec(compile(code, "<model editor, run 1>", "exec"), {})
    ... except ZeroDivisionError as err:
    ...     text, line = user_traceback(err)
    >>> line, text.splitlines()[-1]
    (2, 'ZeroDivisionError: division by zero')
    """
    if isinstance(err, SyntaxError) and str(err.filename or "").startswith(SOURCE):
        caret = ""
        if err.text:
            offset = max(1, err.offset or 1)
            caret = f"\n    {err.text.rstrip()}\n    {' ' * (offset - 1)}^"
        return f"line {err.lineno}: SyntaxError: {err.msg}{caret}", err.lineno
    frames = [f for f in traceback.extract_tb(err.__traceback__) if f.filename.startswith(SOURCE)]
    lines = [f"line {f.lineno}, in {f.name}\n    {(f.line or '').strip()}" for f in frames]
    lines.append("".join(traceback.format_exception_only(type(err), err)).strip())
    return "\n".join(lines), frames[-1].lineno if frames else None


def check_model(model: Model, samples: int = 12) -> list[str]:
    """Call ``model`` as the panels will (float64 points on a ``samples``^dim grid of its bounds, default
    parameters) and say what would make it unusable; returns warnings (no surface in the box).

    Raises
    ------
    ValueError : no bounds declared, a dimension other than 2 or 3, non-finite values.
    Whatever the model's code raises when called.

    Examples
    --------
    >>> from pyfrep_core import Param, model, sphere
    >>> @model(bounds=((-1,) * 3, (1,) * 3), r=Param(0.5, 0.1, 0.9))
    ... def ball(x, r):
    ...     return sphere(x, r=r)
    >>> check_model(ball)
    []
    >>> @model(bounds=((2,) * 3, (3,) * 3), r=Param(0.5, 0.1, 0.9))
    ... def far(x, r):
    ...     return sphere(x, r=r)
    >>> check_model(far)[0]
    'f < 0 at every sampled point of the bounds: no solid to show there (f >= 0 inside); move or enlarge the bounds'
    """
    name = model.__name__
    if model.dim not in (2, 3):
        raise ValueError(f"{name}: the workbench shows 2-D and 3-D models, this one has dim={model.dim}")
    if model.bounds is None:
        box = "((xmin, ymin, zmin), (xmax, ymax, zmax))" if model.dim == 3 else "((xmin, ymin), (xmax, ymax))"
        raise ValueError(f"{name}: declare the box to show it in: @model(bounds={box}, ...)")
    lo, hi = model.bounds
    axes = [torch.linspace(a, b, samples, dtype=torch.float64) for a, b in zip(lo, hi)]
    points = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, model.dim)
    with torch.no_grad():
        values = model(points)
    bad = ~torch.isfinite(values)
    if bool(bad.any()):
        where = points[bad.nonzero()[0, 0]].tolist()
        raise ValueError(
            f"{name} gives {int(bad.sum())} non-finite values at {len(values)} points of its bounds, "
            f"e.g. {float(values[bad][0])} at {[round(v, 4) for v in where]}"
        )
    if bool((values < 0).all()):
        return [
            "f < 0 at every sampled point of the bounds: no solid to show there (f >= 0 inside); "
            "move or enlarge the bounds"
        ]
    if bool((values > 0).all()):
        return ["f > 0 at every sampled point of the bounds: the box is inside the solid; enlarge the bounds"]
    return []


def _user_namespace() -> dict[str, Any]:
    """The kernel's user namespace (where a notebook's cells run), else a fresh one."""
    try:
        from IPython import get_ipython
    except ImportError:
        return {}
    shell = get_ipython()
    return shell.user_ns if shell is not None else {}


class ModelPanel(widgets.VBox):
    """A code editor with templates, Run, the error or the result, and the model shown beside.

    Parameters
    ----------
    template : the template first in the editor (a key of ``TEMPLATES``).
    namespace : where the code runs; default the kernel's user namespace.
    backend : 3-D view backend of the preview.
    preview : options of the preview :class:`~workbench.shape_panel.ShapePanel` (e.g. ``resolution``).

    Attributes
    ----------
    editor : :class:`~workbench.code_editor.CodeEditor`.   model : the model last built (or None).
    on_run : callables given each model built (the app opens it in every panel); what they return
        (the tabs that opened it) is shown.
    shape : the preview ShapePanel, made at the first successful Run.
    """

    def __init__(
        self,
        template: str = "Fig. 1 part",
        namespace: dict[str, Any] | None = None,
        backend: str = "auto",
        preview: dict[str, Any] | None = None,
    ):
        if template not in TEMPLATES:
            raise ValueError(f"template must be one of {', '.join(map(repr, TEMPLATES))}, got {template!r}")
        self.namespace = _user_namespace() if namespace is None else namespace
        self.backend = backend
        self.preview_options = {"resolution": 96, "size": (480, 380), **(preview or {})}
        self.on_run: list[Callable[[Model], Any]] = []
        self.model: Model | None = None
        self.shape: Any = None
        self.runs = 0
        self.template = widgets.Dropdown(
            options=list(TEMPLATES), value=template, description="template", layout=widgets.Layout(width="360px")
        )
        self.editor = CodeEditor(TEMPLATES[template], width="700px")  # the templates' 86 columns
        self.run_button = widgets.Button(
            description="Run", button_style="success", icon="play", tooltip="build the model and open it in every tab"
        )
        self.status = widgets.HTML("edit the code, then Run")
        self.error = widgets.HTML()
        self.preview_box = widgets.VBox([widgets.HTML("<i>Run shows the model here, with one slider per Param.</i>")])
        self.template.observe(lambda change: self.load_template(change["new"]), names="value")
        self.run_button.on_click(lambda _: self.run())
        left = widgets.VBox(
            [
                widgets.HTML(HELP, layout=widgets.Layout(width="750px")),
                widgets.HBox([self.template, self.run_button]),
                self.editor,
                self.status,
                self.error,
            ],
            layout=widgets.Layout(width="760px", flex="0 0 auto", margin="0 16px 0 0"),
        )
        super().__init__([widgets.HBox([left, self.preview_box])])
        self.add_class("pyfrep-model-panel")

    def load_template(self, name: str) -> None:
        """Put template ``name`` in the editor (replacing its code)."""
        self.editor.value = TEMPLATES[name]
        self.error.value = ""
        self.status.value = "edit the code, then Run"

    # -- Run ----------------------------------------------------------------------------------
    def run(self, code: str | None = None) -> Model | None:
        """Build the editor's code (or ``code``, put in the editor); returns the model, or None on error."""
        if code is not None:
            self.editor.value = code
        code = self.editor.value
        self.runs += 1
        filename = f"{SOURCE}, run {self.runs}>"
        linecache.cache[filename] = (len(code), None, code.splitlines(True), filename)  # tracebacks show lines
        t0 = time.perf_counter()
        try:
            tree = ast.parse(code, filename)
            exec(compile(tree, filename, "exec"), self.namespace)  # noqa: S102  (the user's own code, their kernel)
        except Exception as err:  # noqa: BLE001  (whatever the user's code raises is shown, with its line)
            return self._failed(err, "the code")
        models = [self.namespace.get(n) for n in _defined_names(tree)]
        models = [m for m in models if isinstance(m, Model)]
        if not models:
            return self._failed(
                None,
                "the code",
                "no model defined: decorate a function with @model(bounds=..., name=Param(default, lower, upper))",
            )
        model = models[-1]
        try:
            warnings = check_model(model)
        except Exception as err:  # noqa: BLE001
            return self._failed(err, f"calling {model.__name__}")
        seconds = time.perf_counter() - t0
        self.model = model
        self.editor.mark(None)
        self.error.value = ""
        register(model)
        opened: list[str] = []
        for callback in self.on_run:
            try:
                opened.extend(callback(model) or [])
            except Exception as err:  # noqa: BLE001  (one tab failing must not hide the model)
                warnings.append(f"a tab could not open it: {type(err).__name__}: {err}")
        self._preview(model)
        params = ", ".join(f"{k} in [{p.lower:g}, {p.upper:g}]" for k, p in model.params.items()) or "no parameters"
        where = f"; opened in {', '.join(opened)} (the other tabs open it when shown)" if opened else ""
        note = "".join(f"<br><span style='color:#a60'>{html.escape(w)}</span>" for w in warnings)
        self._say(
            f"<b>{html.escape(model.__name__)}</b> built in {1000 * seconds:.0f} ms ({html.escape(params)})"
            f"{html.escape(where)}{note}"
        )
        return model

    def _say(self, text: str) -> None:
        self.status.value = f"<div style='line-height:1.4'>{text}</div>"

    def _failed(self, err: BaseException | None, what: str, message: str = "") -> None:
        line = None
        if err is not None:
            message, line = user_traceback(err)
        self.editor.mark(line)
        at = f" at line {line}" if line is not None else ""
        self._say(f"<span style='color:#b00'><b>error in {html.escape(what)}{at}</b></span>")
        self.error.value = (
            "<pre style='color:#900;background:#fff3f3;padding:6px;white-space:pre-wrap;max-width:640px;"
            "line-height:1.35'>"
            f"{html.escape(message)}</pre>"
        )
        return None

    def _preview(self, model: Model) -> None:
        if model.dim != 3:
            self.preview_box.children = (widgets.HTML("<i>a 2-D model: see it in the Slices tab</i>"),)
            return
        if self.shape is None:
            from .shape_panel import ShapePanel

            self.shape = ShapePanel(model, backend=self.backend, **self.preview_options)
            self.preview_box.children = (self._stacked(self.shape),)
        else:
            self.shape.set_model(model)

    @staticmethod
    def _stacked(shape: Any) -> widgets.Widget:
        """The shape panel with its view above its sliders (beside the editor, the page stays narrow)."""
        row = shape.children[0] if shape.children else None
        if isinstance(row, widgets.HBox) and len(row.children) == 2:
            controls, view = row.children
            return widgets.VBox([view, controls, *shape.children[1:]])
        return shape


def model_panel(backend: str = "auto", **kwargs: Any) -> ModelPanel:
    """The Model tab: write a model, Run, see it with its sliders (and in every tab of the app).

    Examples
    --------
    >>> panel = model_panel(backend="image", namespace={}, preview={"resolution": 24, "threaded": False})
    >>> panel.run().__name__, list(panel.shape.sliders)
    ('my_part', ['r'])
    >>> panel.run("@model(bounds=((-1,) * 3, (1,) * 3))\\ndef broken(x):\\n    return x[:, 3]\\n")
    >>> panel.editor.marked, "IndexError" in panel.error.value
    (3, True)
    >>> panel.shape.view.close()
    """
    return ModelPanel(backend=backend, **kwargs)
