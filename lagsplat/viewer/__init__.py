"""Interactive viewer: grab the identified model with the mouse (``python -m lagsplat view system=<name>``).

* :mod:`lagsplat.viewer.session`: :class:`Session`, the model state and the
  drag (no web dependency; unit-testable).
* :mod:`lagsplat.viewer.drag` and :mod:`lagsplat.viewer.mobility`: the drag as
  part of the dynamics; where a grab moves the image and how stiff the loaded
  system is (the session's parts).
* :mod:`lagsplat.viewer.server`: the local web page (aiohttp, websocket) that
  shows the live render and forwards pointer events.
* :mod:`lagsplat.viewer.synthetic`: a hand-built pendulum system (no training)
  for tests and benchmarks.
"""

from lagsplat.viewer.session import PARAM_RANGE, Session, load_session

__all__ = ["PARAM_RANGE", "Session", "load_session"]
