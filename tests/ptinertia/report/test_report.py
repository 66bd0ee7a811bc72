"""``ptinertia report``: a self-contained page from a run log, a raw log, a result document.

The realistic i3 recording (20 s sweep, ``--realistic``: noise, 1 % gains, 1 deg,
2 mm, residual unbalance) is made once per test session and shared with
``test_resim.py``, ``test_export.py`` and ``test_report_browser.py`` through
:func:`realistic_log` (cached in pytest's session temp directory).
"""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest
from support.report_logs import no_estimate_log, realistic_log

from ptinertia.cli import main
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.report.build import build_report, make_report
from ptinertia.report.data import load
from ptinertia.report.stats import principal_stats, tensors
from ptinertia.reprocess import reprocess_log

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _images(html: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([^"]+)"', html)]


def test_run_log_report_is_self_contained_and_complete(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    log, _ = realistic_log(tmp_path_factory)
    out = tmp_path / "report.html"
    code = main(["report", str(log), "--out", str(out), "--png", str(tmp_path / "png")])
    assert code == 0
    html = out.read_text(encoding="utf-8")
    assert out.stat().st_size < 5e6
    # self-contained: no script, no stylesheet link, nothing fetched from anywhere
    assert "<script" not in html and "<link" not in html
    assert not re.search(r'(src|href)="(?!data:)', html)
    for heading in (
        "1. Estimate",
        "2. Convergence with rpm",
        "3. Orders and re-simulation",
        "4. Rigidity residual",
        "5. Rigid-body modes",
        "6. What was gated out",
        "7. Settings",
    ):
        assert heading in html
    images = _images(html)
    assert len(images) >= 7 and all(i.startswith(PNG_MAGIC) for i in images)
    pngs = sorted((tmp_path / "png").glob("*.png"))
    assert {p.stem for p in pngs} >= {
        "convergence",
        "order-1",
        "order-1_5",
        "order-2",
        "resim",
        "residual",
        "modes",
    }
    assert sorted(p.read_bytes() for p in pngs) == sorted(images)  # the same figures, byte for byte
    # the check's verdict is stated (the numbers themselves are tested in test_resim.py)
    assert "PASS" in html and "re-simulation within 0.5 dB and 5 deg" in html
    # truth beside every term, with the error
    assert "truth (simulation)" in html
    for term in ("Ixx", "Iyz", "Gx", "I1 (principal)", "axis of I3"):
        assert f'<td class="l">{term}</td>' in html


def test_table_values_are_the_estimate_and_the_truth(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    log, doc_path = realistic_log(tmp_path_factory)
    doc = json.loads(doc_path.read_text(encoding="utf-8"))
    html = build_report(load(log)).html
    row = re.search(
        r'<td class="l">Ixx</td><td class="l">kg m\^2</td><td class="">([^<]+)</td>'
        r'<td class="">([^<]+)</td><td class="">([^<]+)</td>',
        html,
    )
    assert row is not None
    value, ci, truth = row.groups()
    assert float(value) == pytest.approx(doc["inertia_kgm2"]["value"]["Ixx"], abs=5e-5)
    lo, hi = (float(v) for v in ci.split(".."))
    assert (lo, hi) == pytest.approx(doc["inertia_kgm2"]["ci95"]["Ixx"], abs=5e-5)
    assert float(truth) == pytest.approx(doc["truth"]["inertia_kgm2"]["value"]["Ixx"])


def test_result_document_report_with_and_without_bench(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    _, doc = realistic_log(tmp_path_factory)
    bare = make_report(doc, tmp_path / "bare.html")
    assert "result document only" in bare.html
    assert "No bench file with mounts: no modes" in bare.html
    assert "modes" not in bare.figures and bare.check is None
    with_bench = make_report(doc, tmp_path / "bench.html", bench=str(DEFAULT_BENCH))
    assert "modes" in with_bench.figures
    assert "1. Estimate" in with_bench.html and "truth (simulation)" in with_bench.html


def test_log_without_valid_frames_still_reports_why(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    log = no_estimate_log(tmp_path_factory)
    out = tmp_path / "none.html"
    assert main(["report", str(log), "--out", str(out)]) == 0
    html = out.read_text(encoding="utf-8")
    assert "No estimate" in html
    assert "rpm_out_of_range" in html  # the reason, with its count
    assert "outside the estimator&#x27;s rpm range" in html
    images = _images(html)
    assert images and all(i.startswith(PNG_MAGIC) for i in images)  # measured orders still shown


def test_raw_only_log_is_estimated_by_the_report(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    """A raw-only copy of the run's recording gives the run's own estimate, bit for bit."""
    from replay.raw_writer import record_source
    from replay.reader import open_log
    from replay.source import McapSource

    log, _ = realistic_log(tmp_path_factory)
    recorded = open_log(log)
    raw = tmp_path / "raw.mcap"
    record_source(McapSource(recorded), raw, bench_text=recorded.bench_text, truth=recorded.truth)
    data = load(raw, reprocess=reprocess_log)
    assert data.kind.startswith("raw recording")
    assert any("raw-only recording" in n for n in data.notes)
    assert data.result is not None and recorded.result is not None
    assert data.result["inertia_kgm2"] == recorded.result["inertia_kgm2"]
    assert data.result["cog_m"] == recorded.result["cog_m"]
    assert "estimated by the report" in build_report(data).html


def test_principal_intervals_match_first_order_theory() -> None:
    """Sampled intervals of the principal moments against the first-order perturbation formula.

    For a symmetric tensor with distinct eigenvalues, ``d lambda_k = v_k^T dI v_k``, so
    ``var(lambda_k) = g_k^T C g_k`` with ``g_k[i] = v_k^T (dI / d theta_i) v_k``.
    """
    terms = np.array([4.6, 3.1, 4.2, 0.28, -0.42, 0.21])
    rng = np.random.default_rng(3)
    a = rng.standard_normal((6, 6)) * 0.004
    cov = a @ a.T  # correlated, small: the first-order formula holds
    stats = principal_stats(terms, cov, samples=40000, seed=1)
    moments, vec = np.linalg.eigh(tensors(terms))
    np.testing.assert_allclose(stats.moments, moments, rtol=1e-12)
    basis = tensors(np.eye(6))  # dI / d theta_i
    for k in range(3):
        g = np.einsum("i,nij,j->n", vec[:, k], basis, vec[:, k])
        std = float(np.sqrt(g @ cov @ g))
        lo, hi = stats.moments_ci95[k]
        assert (hi - lo) / (2 * 1.959964) == pytest.approx(std, rel=0.03)
        assert 0.5 * (lo + hi) == pytest.approx(moments[k], abs=0.05 * std)
    # the axes' cones scale with the uncertainty (x2 std -> x2 angle at small angles)
    wider = principal_stats(terms, 4 * cov, samples=40000, seed=1)
    np.testing.assert_allclose(wider.cone95_deg / stats.cone95_deg, 2.0, rtol=0.06)


def test_run_cut_short_reports_its_last_published_estimate(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    """A recording whose writer died (no footer, no final result) still gives a report."""
    log, _ = realistic_log(tmp_path_factory)
    cut = tmp_path / "cut.mcap"
    data = log.read_bytes()
    cut.write_bytes(data[: int(0.6 * len(data))])
    loaded = load(cut)
    assert loaded.result is not None and loaded.convergence is not None
    assert any("without a final estimate" in n for n in loaded.notes)
    assert any("unfinished recording" in n for n in loaded.notes)
    last = loaded.convergence.value[-1, loaded.convergence.names.index("Ixx")]
    assert loaded.result["inertia_kgm2"]["value"]["Ixx"] == last
    html = build_report(loaded).html
    assert "1. Estimate" in html and "without a final estimate" in html
