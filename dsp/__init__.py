"""Streaming order tracking: crank angle from the tacho, order complex amplitudes per cycle.

Knows nothing of mechanics: imports only numpy, scipy and the stream contract
(:mod:`acquisition.stream`).

* :class:`dsp.tacho.TachoConfig`, :class:`dsp.config.OrderTrackerConfig`: plain
  configuration; :func:`dsp.config.make_plan` binds one to a stream layout.
* :class:`dsp.orders.OrderTracker` (``from_layout``, ``process(item) -> (frames,
  events)``) and its pure twin :func:`dsp.orders.track` (``state, frames =
  track(state, item)``).
* :func:`dsp.driver.track_source`: frames and events of a whole source.
* :class:`dsp.frames.OrderFrame`: the output; :mod:`dsp.errors`: the one exception.
"""
