"""Progress events, callbacks and stopping for long-running algorithms (training, fitting, meshing).

Every long algorithm takes ``callback`` (called with an :class:`Event` every ``every`` steps;
returning True stops the run), ``stop`` (any object with ``is_set()``, e.g. a
``threading.Event`` the workbench's Stop button sets) and ``progress`` (show a tqdm bar).
They never print otherwise.

>>> events = []
>>> with Progress(total=10, stage="demo", callback=events.append, every=5, progress=False) as p:
...     for step in range(10):
...         if p.update(step, loss=1.0 / (step + 1)):
...             break
>>> [e.step for e in events]
[0, 5, 9]
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from tqdm.auto import tqdm


class StopFlag(Protocol):
    def is_set(self) -> bool: ...


@dataclass
class Event:
    """One progress report: stage name, step within the stage, stage length, loss, parameters."""

    stage: str
    step: int
    total: int
    loss: float
    params: dict[str, float] | None = None
    elapsed: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)


class Progress:
    """Bookkeeping for one stage: tqdm bar, periodic callback, stop requests.

    ``update(step, loss, params)`` returns True when the run should stop (the callback
    returned True or the stop flag is set).  The last step is always reported.
    """

    def __init__(
        self,
        total: int,
        stage: str,
        callback: Callable[[Event], Any] | None = None,
        every: int = 10,
        stop: StopFlag | None = None,
        progress: bool = True,
        delay: float = 0.0,
    ):
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.total, self.stage, self.callback, self.every, self.stop = total, stage, callback, every, stop
        # delay: the bar appears only once the stage has run that many seconds (tqdm's delay)
        self.bar = tqdm(total=total, desc=stage, disable=not progress, leave=False, delay=delay)
        self.start = time.perf_counter()
        self.stopped = False

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.bar.close()

    def update(self, step: int, loss: float = float("nan"), params: dict[str, float] | None = None, **extra) -> bool:
        self.bar.update(1)
        if step % self.every == 0 or step == self.total - 1:
            if loss == loss:  # a stage without a loss (meshing) shows none, not "loss=nan"
                self.bar.set_postfix(loss=f"{loss:.3e}", refresh=False)
            if self.callback is not None:
                event = Event(
                    self.stage, step, self.total, float(loss), params, time.perf_counter() - self.start, extra
                )
                if self.callback(event) is True:
                    self.stopped = True
        if self.stop is not None and self.stop.is_set():
            self.stopped = True
        return self.stopped
