"""Matplotlib figures shown as PNG in ``ipywidgets.Image``: live loss charts, plots of slices.

Why images and not ipympl: they need no front-end extension, never show twice, draw the same
under Voila, nbval and pytest, and a figure is private (``matplotlib.figure.Figure``, no pyplot
state), so a background thread can fill a chart while the main thread draws another.
"""

from __future__ import annotations

import io
import threading
import time
from collections.abc import Callable

import ipywidgets as widgets
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["LineChart", "figure_png", "new_figure"]


DPI = 96  # one image pixel per CSS pixel (1/96 in): points on the figure are points on the page


def new_figure(width: float = 5.0, height: float = 3.2, dpi: int = DPI) -> Figure:
    """A private matplotlib figure (Agg canvas attached; nothing global touched).

    At :data:`DPI` a PNG shown at its own size shows a 10 pt font at 10 pt (at 90 dpi it was 9.4).
    """
    fig = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig: Figure) -> bytes:
    """The figure rendered to PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


class LineChart:
    """A chart of named series growing point by point, shown in ``self.widget`` (an Image).

    ``add`` may be called from any thread; ``refresh`` redraws at most every ``min_interval``
    seconds (the last point always shows after ``refresh(force=True)``).

    Parameters
    ----------
    title, xlabel, ylabel : labels.
    logy : log-scale y axis (losses).
    schedule : how a redraw reaches the main thread, ``schedule(fn)``; default: call now.

    Examples
    --------
    >>> chart = LineChart("loss", logy=True)
    >>> for step in range(3):
    ...     chart.add("sgd", step, 10.0**-step)
    >>> chart.refresh(force=True)
    >>> chart.n_points, chart.last("sgd"), bytes(chart.widget.value[:4])
    (3, 0.01, b'\x89PNG')
    """

    def __init__(
        self,
        title: str,
        xlabel: str = "step",
        ylabel: str = "",
        logy: bool = False,
        size: tuple[float, float] = (5.0, 3.2),
        min_interval: float = 0.3,
        schedule: Callable[[Callable], None] | None = None,
    ):
        self.title, self.xlabel, self.ylabel, self.logy = title, xlabel, ylabel, logy
        self.size, self.min_interval = size, min_interval
        self.schedule = schedule or (lambda fn: fn())
        self.series: dict[str, tuple[list[float], list[float]]] = {}
        self.references: dict[str, float] = {}
        self._lock = threading.Lock()
        self._last_draw = 0.0
        self._queued = False
        self.draws = 0
        self.widget = widgets.Image(format="png", layout=widgets.Layout(width=f"{int(size[0] * DPI)}px"))
        self.draw()

    @property
    def n_points(self) -> int:
        with self._lock:
            return sum(len(xs) for xs, _ in self.series.values())

    def last(self, name: str) -> float | None:
        with self._lock:
            ys = self.series.get(name, ([], []))[1]
            return ys[-1] if ys else None

    def add(self, name: str, x: float, y: float) -> None:
        """Append one point (x, y) to series ``name`` (created on first use)."""
        with self._lock:
            xs, ys = self.series.setdefault(name, ([], []))
            xs.append(float(x))
            ys.append(float(y))

    def set_reference(self, name: str, value: float) -> None:
        """A dashed horizontal line (a known true value), coloured like series ``name``."""
        with self._lock:
            self.references[name] = float(value)

    def clear(self) -> None:
        with self._lock:
            self.series.clear()
            self.references.clear()
        self.refresh(force=True)

    def refresh(self, force: bool = False) -> None:
        """Redraw if ``min_interval`` has passed since the last draw and no redraw waits to run
        (always when forced): a busy main thread never has a queue of charts to draw."""
        now = time.monotonic()
        if force or (not self._queued and now - self._last_draw >= self.min_interval):
            self._last_draw = now
            self._queued = True
            self.schedule(self._queued_draw)

    def _queued_draw(self) -> None:
        self._queued = False
        self.draw()

    def draw(self) -> None:
        fig = new_figure(*self.size)
        ax = fig.add_subplot()
        with self._lock:
            series = {k: (list(x), list(y)) for k, (x, y) in self.series.items()}
            refs = dict(self.references)
        colours = {}
        for name, (xs, ys) in series.items():
            if self.logy:
                pairs = [(a, b) for a, b in zip(xs, ys) if b > 0]
                xs, ys = [a for a, _ in pairs], [b for _, b in pairs]
            (line,) = ax.plot(xs, ys, lw=1.5, label=name, marker="." if len(xs) < 40 else None)
            colours[name] = line.get_color()
        for name, value in refs.items():
            ax.axhline(value, ls="--", lw=1, color=colours.get(name, "0.4"))
        if self.logy and any(series.values()):
            ax.set_yscale("log")
        if series:
            ax.legend(fontsize=10, loc="best")
        else:
            ax.text(0.5, 0.5, "no data yet", ha="center", va="center", transform=ax.transAxes, color="0.5")
        ax.set_title(self.title, fontsize=11)
        ax.set_xlabel(self.xlabel, fontsize=10)
        ax.set_ylabel(self.ylabel, fontsize=10)
        ax.tick_params(labelsize=10)
        ax.grid(alpha=0.3)
        self.widget.value = figure_png(fig)
        self.draws += 1
