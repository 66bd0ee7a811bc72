"""What lands in a saved ``.rrd`` (read back with Rerun's own ``RrdReader``): every entity
with data, the frames, the two-sigma bands, the box, the motion, the blueprint; the run
command saving a view; a connect to a listening server on 127.0.0.1.
"""

from __future__ import annotations

import io
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.viewer_checks import closed_port, uniform_box_moments

from acquisition.stream import SourceEvent, StreamLayout
from dsp.frames import OrderFrame
from estimator.result import EstimateUpdate, principal_axes
from estimator.streaming import InertiaEstimator
from ptinertia.config import load_bench
from ptinertia.errors import UsageError
from ptinertia.sinks import RunContext
from ptinertia.to_estimator import estimator_setup
from ptinertia.to_physics import build_simulated_model
from ptinertia.viewer.options import open_recording, parse_rerun_option
from ptinertia.viewer.rerun_sink import RerunSink, ViewerMode, estimate_rows

ROOT = Path(__file__).resolve().parents[3]


# -- the saved recording ----------------------------------------------------------------------


def _read_rrd(path: Path) -> tuple[dict[str, list], dict[str, list], list[tuple[str, str]]]:
    """Temporal and static record batches per entity path, and the blueprint's (view class, origin)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    temporal: dict[str, list] = {}
    static: dict[str, list] = {}
    for chunk in reader.stream().to_chunks():
        if chunk.num_rows == 0:
            continue
        target = static if chunk.is_static else temporal
        target.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    views = []
    for bp in reader.blueprints():
        for chunk in reader.stream(store=bp).to_chunks():
            batch = chunk.to_record_batch()
            if "ViewBlueprint:space_origin" in batch.schema.names:
                views.append(
                    (
                        batch.column("ViewBlueprint:class_identifier").to_pylist()[0][0],
                        batch.column("ViewBlueprint:space_origin").to_pylist()[0][0],
                    )
                )
    return temporal, static, views


def _rows(batches: list, column: str) -> tuple[np.ndarray, list]:
    """(time in s, values) of one component over all batches, in time order."""
    times, values = [], []
    for b in batches:
        if column not in b.schema.names:
            continue
        times += [t / 1e9 for t in b.column("time").cast("int64").to_pylist()]
        values += b.column(column).to_pylist()
    order = np.argsort(times, kind="stable")
    return np.asarray(times)[order], [values[i] for i in order]


class _Clock:
    """A wall clock that jumps 0.3 s per reading: the sink flushes every other frame."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        self.now += 0.3
        return self.now


@pytest.fixture(scope="module")
def saved_run(i3_simulated, tmp_path_factory):
    """Exact frames of a 1500-4500 rpm sweep through the real estimator into a saved view."""
    path = tmp_path_factory.mktemp("viewer") / "run.rrd"
    # flushed as a live view is (a saved file is sent once at the end by default)
    return _save_view(i3_simulated, path, flush_period_s=0.5)


def _save_view(i3_simulated, path, **options):
    bench, model, truth = i3_simulated
    setup = estimator_setup(bench)
    estimator = InertiaEstimator(setup)
    orders = tuple(bench.dsp.orders)
    rpms = np.linspace(1500.0, 4500.0, 40)
    times = np.cumsum(np.full(rpms.size, 0.15))
    amps = model.channel_amplitudes(rpms, orders)
    context = RunContext(
        "", bench, StreamLayout(()), setup, truth, {"dsp": {"orders": list(orders)}}, "sim"
    )
    out = io.StringIO()
    sink = RerunSink(ViewerMode("save", path=path), out=out, clock=_Clock(), **options)
    sink.start(context)
    n_ch = len(model.channel_names)
    last = None
    for i, rpm in enumerate(rpms):
        frame = OrderFrame(
            float(times[i]), float(rpm), 0.0, orders, model.channel_names, amps[i],
            np.ones(n_ch, bool), 0.0, np.zeros(n_ch), frozenset(),
        )  # fmt: skip
        outcome = estimator.update(frame)
        sink.on_frame(frame, outcome)
        if outcome.reason is None:
            last = estimator.estimate()
            sink.on_estimate(EstimateUpdate(frame.time_s, frame.rpm, last))
    sink.on_event(SourceEvent("gap", "3 samples lost", time_s=1.0))
    sink.close(last)
    sink.close(last)  # a second close is harmless
    temporal, static, views = _read_rrd(path)
    return {
        "temporal": temporal, "static": static, "views": views, "rpms": rpms,
        "times": times, "amps": amps, "estimate": last, "truth": truth, "out": out.getvalue(),
        "model": model, "path": path,
    }  # fmt: skip


def _data_chunks(path: Path) -> tuple[int, int]:
    """Chunks of the recording's data store (not its blueprint): all, and the static ones."""
    from rerun.chunk import RrdReader

    chunks = list(RrdReader(path).stream().to_chunks())
    return len(chunks), sum(c.is_static for c in chunks)


def test_a_saved_view_is_as_compact_as_rerun_compacts_it(i3_simulated, tmp_path):
    """One send per entity: ``rerun rrd verify`` passes and ``rrd optimize`` finds nothing to merge."""
    rerun_cli = Path(sys.executable).with_name("rerun")
    if not rerun_cli.exists():
        pytest.skip("the rerun command line of rerun-sdk is not installed beside this Python")
    path = tmp_path / "run.rrd"
    _save_view(i3_simulated, path)
    subprocess.run([rerun_cli, "rrd", "verify", path], check=True, capture_output=True)
    optimized = tmp_path / "optimized.rrd"
    subprocess.run(
        [rerun_cli, "rrd", "optimize", path, "-o", optimized], check=True, capture_output=True
    )
    ours, ours_static = _data_chunks(path)
    best, best_static = _data_chunks(optimized)
    # at most 2x the compacted lower bound (the check). Sent once, the temporal data
    # is the bound; static rows and events go through Rerun's time-ticked batcher, which
    # on a loaded machine may cut one more chunk (64 against 63, seen once)
    assert ours - ours_static <= 2 * (best - best_static)
    assert ours <= 2 * best
    # flushed every 0.6 s of wall time, as a live view, it was not
    live = tmp_path / "live.rrd"
    _save_view(i3_simulated, live, flush_period_s=0.5)
    assert _data_chunks(live)[0] > 2 * best


def test_saved_view_has_every_entity_with_data(saved_run):
    temporal, static = saved_run["temporal"], saved_run["static"]
    expected = ["/rpm", "/quality/relative_residual", "/quality/used_orders", "/events"]
    expected += [f"/orders/H{h:g}/{k}" for h in (1, 1.5, 2) for k in ("amplitude", "phase")]
    expected += [f"/estimate/inertia/{t}" for t in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")]
    expected += [f"/estimate/cog/{g}" for g in ("Gx", "Gy", "Gz")]
    expected += ["/estimate/extra/crank_offset", "/estimate/extra/unbalance"]
    expected += ["/bench/moving", "/bench/moving/powertrain", "/bench/moving/powertrain/box"]
    expected += ["/bench/moving/powertrain/principal_axes", "/bench/cog", "/bench/cog/ellipsoid"]
    missing = [p for p in expected if p not in temporal]
    assert not missing
    for p in ["/bench", "/bench/mounts", "/bench/truth/box", "/bench/nominal_cog"]:
        assert p in static
    sensors = [p for p in static if p.startswith("/bench/moving/sensors/") and p.endswith("/axes")]
    assert len(sensors) == 3
    for batch in temporal["/estimate/inertia/Ixx"]:
        assert {"time", "rpm"} <= set(batch.schema.names)  # both timelines, for Figs. 13/15
    assert "rerun " + str(saved_run["path"]) in saved_run["out"]


def test_saved_rpm_and_orders_are_the_frames(saved_run):
    t, rpm = _rows(saved_run["temporal"]["/rpm"], "Scalars:scalars")
    np.testing.assert_allclose(t, saved_run["times"], atol=1e-9)
    np.testing.assert_allclose(np.ravel(rpm), saved_run["rpms"], rtol=1e-15)
    _, amp = _rows(saved_run["temporal"]["/orders/H1.5/amplitude"], "Scalars:scalars")
    _, phase = _rows(saved_run["temporal"]["/orders/H1.5/phase"], "Scalars:scalars")
    x = saved_run["amps"][:, 1, :]  # order 1.5, every channel
    np.testing.assert_allclose(np.asarray(amp), np.abs(x), rtol=1e-12)
    np.testing.assert_allclose(np.exp(1j * np.radians(phase)), x / np.abs(x), atol=1e-9)


def test_saved_bands_are_two_sigma_around_the_estimate(saved_run):
    est = saved_run["estimate"]
    for name, path in [("Ixy", "/estimate/inertia/Ixy"), ("Gz", "/estimate/cog/Gz")]:
        _, rows = _rows(saved_run["temporal"][path], "Scalars:scalars")
        value, hi, lo, truth = rows[-1]
        expected_truth = (
            saved_run["truth"]["inertia_kgm2"][name]
            if name.startswith("I")
            else saved_run["truth"]["cog_m"][2]
        )
        assert truth == expected_truth
        assert value == pytest.approx(est.value(name), rel=1e-12)
        assert hi - value == pytest.approx(2 * est.std(name), rel=1e-9)
        assert value - lo == pytest.approx(2 * est.std(name), rel=1e-9)
    _, rows = _rows(saved_run["temporal"]["/estimate/inertia/Ixx"], "Scalars:scalars")
    assert rows[-1][3] == saved_run["truth"]["inertia_kgm2"]["Ixx"]  # the flat truth line
    assert estimate_rows(est)["Ixx"] == (est.value("Ixx"), est.std("Ixx"))


def test_saved_box_carries_the_estimated_inertia(saved_run):
    """The drawn box's own inertia (by quadrature) is the final estimate's, on its principal axes."""
    est, temporal = saved_run["estimate"], saved_run["temporal"]
    moments, axes = principal_axes(est.inertia)
    _, half = _rows(temporal["/bench/moving/powertrain/box"], "Boxes3D:half_sizes")
    drawn = uniform_box_moments(np.asarray(half[-1][0]), saved_run["truth"]["mass_kg"])
    np.testing.assert_allclose(drawn, moments, rtol=1e-6)  # float32 in the file
    _, mats = _rows(temporal["/bench/moving/powertrain"], "Transform3D:mat3x3")
    _, trans = _rows(temporal["/bench/moving/powertrain"], "Transform3D:translation")
    mat = np.asarray(mats[-1]).reshape(3, 3).T  # Rerun stores mat3x3 column-major
    np.testing.assert_allclose(np.abs(mat.T @ axes), np.eye(3), atol=1e-5)
    np.testing.assert_allclose(trans[-1][0], est.cog, atol=1e-6)
    # the cog ellipsoid: 2 sigma along the principal directions of the cog covariance
    _, size = _rows(temporal["/bench/cog/ellipsoid"], "Ellipsoids3D:half_sizes")
    var = np.linalg.eigvalsh(est.cov[6:9, 6:9])
    np.testing.assert_allclose(np.sort(size[-1][0]), 2 * np.sqrt(var), rtol=1e-6)


def test_saved_motion_is_animated_and_rigid(saved_run):
    _, mats = _rows(saved_run["temporal"]["/bench/moving"], "Transform3D:mat3x3")
    _, trans = _rows(saved_run["temporal"]["/bench/moving"], "Transform3D:translation")
    assert len(trans) >= 30
    spread = np.ptp(np.asarray(trans, dtype=float), axis=0)
    assert np.max(spread) > 1e-3  # it moves visibly (mm, exaggerated) ...
    for m in mats[:5]:  # ... as a rigid body
        r = np.asarray(m).reshape(3, 3)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-6)


def test_blueprint_views_show_data(saved_run):
    """Every view of the default layout points at an entity that has data: no empty panel."""
    views = saved_run["views"]
    assert ("3D", "/bench") in views
    have = set(saved_run["temporal"]) | set(saved_run["static"])
    for cls, origin in views:
        assert any(p == origin or p.startswith(origin + "/") for p in have), (cls, origin)
    plotted = {o for c, o in views if c == "TimeSeries"}
    assert {"/rpm", "/estimate/inertia/Ixx", "/estimate/cog/Gz", "/orders/H1.5/phase"} <= plotted


def test_mass_is_plotted_when_estimated(tmp_path):
    """The inline 4 has a free order-2 force: mass is estimated and gets its own band plot."""
    bench = load_bench(ROOT / "examples" / "i4-bench.toml")
    model, truth = build_simulated_model(bench)
    setup = estimator_setup(bench)
    assert not setup.mass_known
    estimator = InertiaEstimator(setup)
    orders = tuple(bench.dsp.orders)
    rpms = np.linspace(2000.0, 4500.0, 12)
    amps = model.channel_amplitudes(rpms, orders)
    context = RunContext("", bench, StreamLayout(()), setup, truth, {}, "sim")
    sink = RerunSink(ViewerMode("save", path=tmp_path / "i4.rrd"), out=io.StringIO())
    sink.start(context)
    n_ch = len(model.channel_names)
    est = None
    for i, rpm in enumerate(rpms):
        frame = OrderFrame(
            0.2 * i, float(rpm), 0.0, orders, model.channel_names, amps[i],
            np.ones(n_ch, bool), 0.0, np.zeros(n_ch), frozenset(),
        )  # fmt: skip
        outcome = estimator.update(frame)
        sink.on_frame(frame, outcome)
        if outcome.reason is None:
            est = estimator.estimate()
            sink.on_estimate(EstimateUpdate(frame.time_s, frame.rpm, est))
    sink.close(est)
    temporal, _, views = _read_rrd(tmp_path / "i4.rrd")
    assert ("TimeSeries", "/estimate/extra/mass") in views
    _, rows = _rows(temporal["/estimate/extra/mass"], "Scalars:scalars")
    mass, std = est.mass()
    assert rows[-1][0] == pytest.approx(mass, rel=1e-12)
    assert rows[-1][1] - rows[-1][0] == pytest.approx(2 * std, rel=1e-9)
    assert rows[-1][3] == truth["mass_kg"]


def test_serve_on_a_busy_port_is_a_user_error():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        sink = RerunSink(ViewerMode("serve", port=port), out=io.StringIO())
        with pytest.raises(UsageError, match=f"cannot listen on 127.0.0.1:{port}"):
            sink.start(None)  # type: ignore[arg-type]  # fails before reading the context


def test_run_command_saves_a_view(tmp_path, capsys):
    """``ptinertia run --rerun save=PATH`` end to end on a short simulated sweep."""
    from ptinertia.cli import main

    path = tmp_path / "cli.rrd"
    args = ["run", "--rerun", f"save={path}", "--duration", "3", "--sweep", "2500:3200", "--quiet"]
    assert main(args) == 0
    assert f"rerun {path}" in capsys.readouterr().err
    temporal, static, _ = _read_rrd(path)
    for p in [
        "/rpm",
        "/orders/H1/amplitude",
        "/estimate/inertia/Ixx",
        "/bench/moving/powertrain/box",
    ]:
        assert p in temporal
    assert "/bench/truth/box" in static


def test_connect_streams_to_a_listening_server(i3_simulated):
    """connect= reaches a Rerun server (ours, on 127.0.0.1) and closes without waiting."""
    bench, _, truth = i3_simulated
    port = closed_port()
    server = open_recording(
        ViewerMode("serve", port=port, memory_limit="16MiB"), None, io.StringIO()
    )
    try:
        setup = estimator_setup(bench)
        context = RunContext("", bench, StreamLayout(()), setup, truth, {}, "sim")
        out = io.StringIO()
        # a flush that cannot finish within the timeout warns instead of waiting on
        sink = RerunSink(
            parse_rerun_option(f"connect=127.0.0.1:{port}"), out=out, close_timeout_s=2.0
        )
        sink.start(context)
        sink.on_event(SourceEvent("gap", "test"))
        sink.close(None)
        assert "did not take all the data" not in out.getvalue()
    finally:
        server.disconnect()
