"""A new frame in the trame view as soon as it is encoded, not half a second later.

trame's server-side view sends a picture when told the scene changed: it renders the window,
hands the frame to VTK's encoder (JPEG, on a worker thread) and publishes what the encoder has
ready, which right after a render is the previous picture ("stale").  trame-vtk then asks again
after ``delta_stale_time_before_render`` = 0.5 s, and once more after twice that, then gives
up: every slider move reached the browser at least 0.5 s after its render, and a frame whose
encoding took longer than the retries was never shown until the next move.

:func:`prompt_image_delivery` makes the image-delivery protocol (created per trame server, so
the change is made to its class, once, before a view starts its server) ask again every
``interval`` seconds until the encoder has the new picture, for at most ``patience`` seconds.
Each retry only looks at the encoder's output (no render: the scene has not changed since).
"""

from __future__ import annotations

from typing import Any

__all__ = ["prompt_image_delivery"]

INTERVAL_S = 0.01  # a 640 x 480 JPEG takes a few ms to encode on one core
PATIENCE_S = 3.0


def prompt_image_delivery(interval: float = INTERVAL_S, patience: float = PATIENCE_S) -> bool:
    """Make trame-vtk's image delivery publish a new frame within ``interval`` s of its encoding.

    Returns False (and changes nothing) when trame-vtk is not installed or has no such protocol.

    Examples
    --------
    >>> prompt_image_delivery() in (True, False)
    True
    """
    try:
        from trame_vtk.modules.vtk.protocols.publish_image_delivery import vtkWebPublishImageDelivery
    except ImportError:
        return False
    cls: Any = vtkWebPublishImageDelivery
    if not hasattr(cls, "render_stale_image") or not hasattr(cls, "push_render"):
        return False
    if getattr(cls, "_pyfrep_interval", None) == interval:
        return True
    original_init = getattr(cls, "_pyfrep_original_init", cls.__init__)
    tries = max(1, int(patience / interval))

    def init(self: Any, *args: Any, **kwargs: Any) -> None:
        original_init(self, *args, **kwargs)
        self.delta_stale_time_before_render = interval
        self.stale_count_limit = tries

    def render_stale_image(self: Any, v_id: Any, stale_count: int = 0) -> None:
        # the pushes so far were stale: ask the encoder again (push_render schedules the next try
        # while it still is), at a fixed interval, up to the patience
        if self.stale_handler_count.get(v_id, 0) > 0:
            self.stale_handler_count[v_id] -= 1
        if self.last_stale_time.get(v_id, 0) != 0 and stale_count < self.stale_count_limit:
            self.push_render(v_id, False, stale_count + 1)

    cls._pyfrep_original_init = original_init
    cls.__init__ = init
    cls.render_stale_image = render_stale_image
    cls._pyfrep_interval = interval
    return True
