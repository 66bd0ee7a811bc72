"""Recording the processing results to MCAP: frames, gating, estimates and events round
trip, Foxglove's fields carry the numbers, the documented schema is the one written, an
infinite ratio written as the cap (split from test_mcap_record.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from support.mcap_logs import (
    BENCH_TEXT,
    TRUTH,
    assert_same_items,
    make_frame,
    make_outcome,
    synthetic_items,
    synthetic_layout,
)

from acquisition.stream import (
    SourceEvent,
)
from dsp.frames import OrderFrame
from estimator.outcome import FrameOutcome
from estimator.result import RATIO_CAP, Estimate, EstimateUpdate
from replay.reader import open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo

# -- processing results ---------------------------------------------------------------------------


def make_estimate(k: int, rng: np.random.Generator) -> Estimate:
    names = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz", "Gx", "Gy", "Gz", "inv_mass", "crank_offset")
    n = len(names)
    a = rng.standard_normal((n, n))
    cov_r = a @ a.T * 1e-4
    b = rng.standard_normal((n, n))
    cov_s = b @ b.T * 1e-5
    observable = np.ones(n, bool)
    observable[-1] = k % 2 == 0  # crank offset unobservable every other time: std inf
    theta = np.concatenate(
        [[10.0, 20.0, 25.0, 0.5, -0.3, 0.1, 0.05, -0.01, 0.2, 1 / 140.0, 0.01], []]
    )
    return Estimate(
        names=names,
        theta=theta + 1e-3 * rng.standard_normal(n),
        cov=cov_r + cov_s if k else cov_r + cov_s + 1e-9,  # once not the plain sum
        cov_random=cov_r,
        cov_systematic=cov_s,
        observable=observable,
        mass_known=False,
        mass_nominal=150.0,
        unbalance_point=np.array([0.0, 0.1, 0.0]),
        frames_used=k + 1,
        frames_skipped=k,
        frames_rejected={"rpm_unsteady": k, "tacho": 1},
        orders_rejected={"non_rigid": 2 * k},
        rpm_range=(1500.0, 1500.0 + k),
        half_order=None
        if k % 2
        else {"method": "residual", "half_order_sign": -1, "residual_ratio": math.inf, "frames": 3},
        variance_factor=1.0 + 0.1 * k,
    )


def test_frames_gating_estimates_and_events_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    layout = synthetic_layout()
    items = synthetic_items(layout, 1.0, seed=4)
    frames: list[OrderFrame] = []
    outcomes: list[FrameOutcome] = []
    updates: list[EstimateUpdate] = []
    dsp_events: list[SourceEvent] = []
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path)
    rec.start(RecordingInfo(layout=layout, bench_text=BENCH_TEXT, truth=TRUTH))
    for k, item in enumerate(items):
        rec.on_item(item)
        if isinstance(item, SourceEvent):
            rec.on_event(item)  # the pipeline reports source events twice: recorded once
        if k % 5 == 4:
            frame = make_frame(k / len(items), rng)
            outcome = make_outcome(frame, used=k % 10 != 4)
            rec.on_frame(frame, outcome)
            frames.append(frame)
            outcomes.append(outcome)
            if outcome.reason is None:
                update = EstimateUpdate(frame.time_s, frame.rpm, make_estimate(len(updates), rng))
                rec.on_estimate(update)
                updates.append(update)
            event = SourceEvent("tacho_resync", f"re-synced after frame {k}", None)
            rec.on_event(event)
            dsp_events.append(event)
    rec.close(updates[-1].estimate)

    log = open_log(path)
    got_frames = list(log.frames())
    assert len(got_frames) == len(frames)
    for a, b in zip(got_frames, frames, strict=True):
        for name in (
            "time_s",
            "rpm",
            "crank_angle_rad",
            "orders",
            "channels",
            "rpm_change",
            "flags",
        ):
            assert getattr(a, name) == getattr(b, name), name
        assert a.amplitudes.tobytes() == b.amplitudes.tobytes()
        np.testing.assert_array_equal(a.channel_ok, b.channel_ok)
        assert a.leakage.tobytes() == b.leakage.tobytes()
    got_outcomes = list(log.outcomes())
    assert [
        (o.time_s, o.used_orders, o.rejected, o.reason, o.relative_residual) for o in got_outcomes
    ] == [(o.time_s, o.used_orders, o.rejected, o.reason, o.relative_residual) for o in outcomes]
    got_updates = list(log.estimates())
    assert len(got_updates) == len(updates)
    for u, v in zip(got_updates, updates, strict=True):
        assert (u.time_s, u.rpm) == (v.time_s, v.rpm)
        for name in (
            "theta",
            "cov",
            "cov_random",
            "cov_systematic",
            "observable",
            "unbalance_point",
        ):
            assert getattr(u.estimate, name).tobytes() == getattr(v.estimate, name).tobytes(), name
        assert json.dumps(u.estimate.to_json()) == json.dumps(v.estimate.to_json())
    assert log.result == json.loads(json.dumps(updates[-1].estimate.to_json()))
    final = log.final_estimate()
    assert final is not None and final.theta.tobytes() == updates[-1].estimate.theta.tobytes()
    assert final.cov.tobytes() == updates[-1].estimate.cov.tobytes()
    assert log.message_counts is not None and log.message_counts["/estimate"] == len(updates) + 1
    events = list(log.events())
    assert [e for o, e in events if o == "dsp"] == dsp_events
    assert [e for o, e in events if o == "source"] == [
        i for i in items if isinstance(i, SourceEvent)
    ]
    assert_same_items(list(log.items()), items)  # dsp events are not raw items


def test_foxglove_fields_carry_the_numbers(tmp_path: Path) -> None:
    """Named estimate fields and per-order/per-channel amplitudes, as a plot panel indexes them."""
    from replay.schemas import message_class

    rng = np.random.default_rng(6)
    frame = make_frame(0.25, rng)
    estimate = make_estimate(2, rng)
    layout = synthetic_layout()
    path = tmp_path / "fox.mcap"
    rec = McapRecorder(path)
    rec.start(RecordingInfo(layout=layout))
    rec.on_frame(frame, make_outcome(frame, True))
    rec.on_estimate(EstimateUpdate(0.25, 1525.0, estimate))
    rec.close(None)
    with open(path, "rb") as fh:
        msgs = {c.topic: m.data for _, c, m in make_reader(fh).iter_messages()}
    est = message_class("Estimate").FromString(msgs["/estimate"])
    for name in ("Ixx", "Iyz", "Gz", "crank_offset"):
        assert getattr(est, name) == estimate.value(name)
        assert getattr(est, f"{name}_std") == estimate.std(name)
    assert (est.mass_kg, est.mass_kg_std) == estimate.mass()
    orders = message_class("OrderFrame").FromString(msgs["/orders"])
    entry = next(o for o in orders.by_order if o.order == 1.5)
    ch = next(c for c in entry.channels if c.channel == "s3")
    x = frame.amplitude(1.5, "s3")
    assert ch.amplitude == abs(x)
    assert ch.phase_deg == pytest.approx(math.degrees(math.atan2(x.imag, x.real)), abs=1e-12)


def test_the_documented_schema_is_the_one_written() -> None:
    from replay.schemas import proto_text

    doc = (Path(__file__).resolve().parents[2] / "docs" / "recording-format.md").read_text()
    block = doc.split("```proto\n", 1)[1].split("```", 1)[0]
    assert block.strip() == proto_text().strip()


def test_an_infinite_half_order_ratio_is_written_as_the_cap() -> None:
    # exact data make the losing hypothesis's residual ratio infinite; the result
    # file is strict JSON (no Infinity), so it is written as the cap
    est = make_estimate(0, np.random.default_rng(1))
    assert est.half_order is not None and est.half_order["residual_ratio"] == math.inf
    doc = json.loads(json.dumps(est.to_json(), allow_nan=False))
    assert doc["half_order"]["residual_ratio"] == RATIO_CAP
    assert est.half_order["residual_ratio"] == math.inf  # the estimate itself is not altered
