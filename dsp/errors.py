"""The one exception of the signal-processing layer.

A configuration that cannot work (orders that alias at the sampling rate, a
wheel with more missing teeth than teeth, a channel the source does not have)
raises :class:`DspConfigError` with a one-line message carrying the numbers.
Bad *data* never raises: it is flagged in the frames and reported as events.
"""

from __future__ import annotations


class DspConfigError(ValueError):
    """An order-tracking configuration that cannot work; the message is one line."""
