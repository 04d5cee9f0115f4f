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
A push outside a camera animation first waits for the encoder right there, up to ``wait`` s
(a 640 x 480 JPEG takes a few ms): the picture leaves as soon as it is encoded, instead of after
whatever the kernel does next on its main thread (a panel's status line, the next mesh's
delivery), which the scheduled retries would have to wait for.
"""

from __future__ import annotations

import time
from typing import Any

__all__ = ["prompt_image_delivery", "remote_geometry_on_demand"]

INTERVAL_S = 0.01  # a 640 x 480 JPEG takes a few ms to encode on one core
PATIENCE_S = 3.0
WAIT_S = 0.1  # the longest a push waits for its JPEG before leaving it to the retries


def prompt_image_delivery(interval: float = INTERVAL_S, patience: float = PATIENCE_S, wait: float = WAIT_S) -> bool:
    """Make trame-vtk's image delivery publish a new frame as soon as it is encoded.

    A push waits up to ``wait`` s for its JPEG (polling the encoder every 2 ms); a slower one is
    published by retries every ``interval`` s, for at most ``patience`` s.

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
    if getattr(cls, "_pyfrep_interval", None) == (interval, patience, wait):
        return True
    original_init = getattr(cls, "_pyfrep_original_init", cls.__init__)
    original_push = getattr(cls, "_pyfrep_original_push", cls.push_render)
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

    def push_render(self: Any, v_id: Any, ignore_animation: bool = False, stale_count: int = 0) -> None:
        original_push(self, v_id, ignore_animation, stale_count)
        if self.views_in_animations:  # a camera drag: the animation's own frames follow at its rate
            return
        # stale: the encoder has the picture on its threads; ask again until it is out (the retry
        # scheduled by the push then finds nothing left to do)
        end = time.monotonic() + wait
        while self.last_stale_time.get(v_id, 0) != 0 and time.monotonic() < end:
            time.sleep(0.002)
            original_push(self, v_id, ignore_animation, stale_count)

    cls._pyfrep_original_init = original_init
    cls._pyfrep_original_push = original_push
    cls.__init__ = init
    cls.push_render = push_render
    cls.render_stale_image = render_stale_image
    cls._pyfrep_interval = (interval, patience, wait)
    return True


def remote_geometry_on_demand() -> bool:
    """While pyvista's trame view renders on the server, send it pictures only, not the scene too.

    pyvista's view can switch to rendering in the browser (vtk.js), and to stay ready for that
    trame-vtk's ``VtkRemoteLocalView.update`` serializes the whole scene and sends it along with
    every picture: about 1.7 MB for a 100k-triangle surface, built on the kernel's main thread
    and parsed in the page before the next picture can be shown, for a view nobody sees.  After
    this patch an update in server rendering sends the picture and the scene waits; it is sent
    when the view is switched to browser rendering.  Returns False (and changes nothing) when
    trame-pyvista is not installed or has no such view.

    Examples
    --------
    >>> remote_geometry_on_demand() in (True, False)
    True
    """
    try:
        from trame_pyvista.widgets import PyVistaRemoteLocalView
    except ImportError:
        return False
    cls: Any = PyVistaRemoteLocalView
    if getattr(cls, "_pyfrep_on_demand", False):
        return True
    if not hasattr(cls, "update") or not hasattr(cls, "update_image"):
        return False
    original_update = cls.update

    def update(self: Any, reset_camera: bool = False, **kwargs: Any) -> None:
        plotter = self.plotter
        key = f"{plotter._id_name}_use_server_rendering" if plotter is not None else None
        if key is None or self.server.state[key] is not True:  # browser rendering (or unknown): as before
            original_update(self, reset_camera=reset_camera, **kwargs)
            return
        if getattr(self, "_VtkRemoteLocalView__rendering", True):
            self.update_image(reset_camera)
        if not getattr(self, "_pyfrep_listening", False):
            self._pyfrep_listening = True

            @self.server.state.change(key)
            def _switched(**state: Any) -> None:
                if state.get(key) is False:  # now rendered in the browser: it needs the scene
                    original_update(self)
                    self.push_camera()

    cls.update = update
    cls._pyfrep_on_demand = True
    return True
