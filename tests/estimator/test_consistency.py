"""The estimator says when its model does not fit, and never prints a non-physical tensor
(issue 20, item 4).

References: the simulated truth (an engine burning four times what [gas] says
is a gross misfit; the right model is not), and a tensor built to violate
positive definiteness and the triangle inequality.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import pytest
from support.estimator_runs import I3

from estimator.misfit import CHI2_LIMIT
from estimator.result import enforce_physical, tensor_from_terms
from ptinertia.config import load_bench
from ptinertia.runner import RunOptions, print_table, run_source
from ptinertia.sources import open_source


def _run(**sim: Any) -> tuple[Any, dict[str, Any]]:
    bench = load_bench(I3)
    source = open_source("sim", bench, duration_s=10.0, **sim)
    summary, doc = run_source(bench, I3.read_text(), source, "sim", RunOptions(quiet=True))
    assert doc is not None and summary.estimate is not None
    return summary.estimate, doc


@pytest.mark.parametrize("burn_pct", [0.0, 300.0])
def test_a_gross_misfit_is_named_and_marked_inconsistent(burn_pct: float) -> None:
    estimate, doc = _run(heat_release_error_pct=burn_pct)
    out = io.StringIO()
    assert print_table(estimate, doc, out)  # the tensor is physical either way
    gross = burn_pct > 0
    assert doc["consistent"] is not gross
    assert ("the model does not fit the data" in out.getvalue()) is gross
    if gross:
        m = doc["misfit"]
        assert m["chi2_per_dof"] > CHI2_LIMIT and m["order"] in (1.0, 1.5, 2.0)
        assert m["equation"].startswith("moment") and "[gas]" in m["likely_inputs"]
    else:
        assert doc["misfit"] is None


def test_an_unbalance_off_the_reference_point_points_to_its_location() -> None:
    """Pinned at the reference point, a 1 g m unbalance 80 mm along the crank misfits
    (issue 20's case: Izz +34 %): the line names the switch that estimates its location."""
    off = {
        "residual_unbalance_kgm": 1e-3,
        "residual_unbalance_deg": 120.0,
        "residual_unbalance_axial_m": 0.08,
    }
    _, doc = _run(**off)
    assert doc["consistent"] is False
    assert "unbalance_location = true" in doc["misfit"]["likely_inputs"]


@pytest.mark.parametrize(
    "terms",
    [
        [4.6, -3.0, 4.2, 0.28, -0.42, 0.21],  # not positive definite
        [1.0, 1.0, 4.0, 0.0, 0.0, 0.0],  # I1 + I2 < I3
    ],
)
def test_a_non_physical_tensor_is_never_printed_as_an_estimate(
    terms: list[float], capsys: pytest.CaptureFixture[str]
) -> None:
    estimate, doc = _run()
    theta = estimate.theta.copy()
    theta[:6] = terms
    from dataclasses import replace

    bad = replace(estimate, theta=theta)
    assert enforce_physical(tensor_from_terms(np.array(terms)))[1]
    bad_doc = {**bad.to_json(doc.get("truth")), "source": "sim"}
    assert bad_doc["consistent"] is False
    out = io.StringIO()
    assert not print_table(bad, bad_doc, out)
    assert out.getvalue() == ""  # no table
    assert "no estimate to stand behind: the fitted inertia tensor is" in capsys.readouterr().err
