"""FrameOutcome's hand-written __init__ (estimator/outcome.py) against its dataclass
fields: the same parameters, order and defaults, and the record still frozen."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

from estimator.outcome import FrameOutcome


def test_the_init_takes_the_fields_in_order_with_their_defaults() -> None:
    params = list(inspect.signature(FrameOutcome.__init__).parameters.values())[1:]
    fields = dataclasses.fields(FrameOutcome)
    assert [p.name for p in params] == [f.name for f in fields]
    for p, f in zip(params, fields, strict=True):
        assert f.default_factory is dataclasses.MISSING  # (the __init__ does not call one)
        want = inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default
        assert p.default == want


def test_the_record_is_frozen_and_compares_by_value() -> None:
    a = FrameOutcome(1.0, 2000.0, (1.0, 2.0), {1.5: "gate"}, None, {1.0: 0.01})
    b = FrameOutcome(
        time_s=1.0, rpm=2000.0, used_orders=(1.0, 2.0), rejected={1.5: "gate"}, reason=None,
        relative_residual={1.0: 0.01},
    )  # fmt: skip
    assert a == b and a.motion is None and dataclasses.replace(a, rpm=2100.0).rpm == 2100.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.rpm = 1.0  # type: ignore[misc]
