"""Self-calibration: each channel's gain and each sensor's alignment estimated with the rest.

The declared tolerances are the priors. Through the whole chain (simulated i3, real
dsp): with misaligned sensors alone the products of inertia move by several % of their
own value; estimating the calibration takes them back under 0.5 %. (The individual
angles and gains are not all observable: the sweep pins the combinations that matter
for the inertia, the priors hold the rest.)
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
from support.estimator_runs import cog_error_m, rel_errors, run

from ptinertia.config import ConfigError, load_bench, loads_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import make_estimator

I3 = EXAMPLES_DIR / "i3-bench.toml"
# sensor errors only (noise-free, exact positions): what the calibration can undo
SENSOR_ERRORS = {"duration_s": 20.0, "misalignment_deg": 1.0, "seed": 2}


def _bench(self_calibration: bool):
    bench = load_bench(I3)
    est = bench.estimator.model_copy(update={"self_calibration": self_calibration})
    return bench.model_copy(update={"estimator": est})


def _errors(self_calibration: bool) -> tuple[dict[str, float], dict[str, Any]]:
    doc = run(I3, SENSOR_ERRORS, estimator={"self_calibration": self_calibration})
    return rel_errors(doc), doc


def test_calibration_undoes_misalignment():
    plain, _ = _errors(False)
    assert max(abs(plain[k]) for k in ("Ixy", "Ixz", "Iyz")) > 0.02, plain
    calibrated, doc = _errors(True)
    assert max(abs(e) for e in calibrated.values()) < 0.005, calibrated
    assert np.all(cog_error_m(doc) < 0.0005)


def test_calibration_parameters_and_priors():
    est = make_estimator(_bench(True))
    names = est.layout.names
    cal = [n for n in names if n.startswith("cal:")]
    assert len(cal) == 9 + 9  # nine channel gains, three angles per sensor
    # before any frame only the priors inform them: the declared tolerances
    info = est.acc[1].state.info
    idx = [names.index(n) for n in cal]
    stds = 1.0 / np.sqrt(np.diag(info)[idx])
    np.testing.assert_allclose(stds[:9], 0.01)
    np.testing.assert_allclose(stds[9:], np.radians(1.0))
    assert not any(n.startswith("cal:") for n in make_estimator(_bench(False)).layout.names)


def test_a_clean_sweep_keeps_every_calibrated_parameter_and_the_cog():
    # At 60 dB the rows know the motion 1e12 times better than the priors know a
    # gain or an angle. The rank decision once threw the prior-held directions away
    # and the cog's y with them: Gy "unobservable", written as 0, 85 mm off.
    doc = run(
        I3,
        {"duration_s": 40.0, "noise_snr_db": 60.0, "position_error_m": 0.002, "seed": 3},
        estimator={"self_calibration": True},
    )
    assert doc["unobservable"] == []
    assert np.all(cog_error_m(doc) < 0.002)


def test_noise_alone_does_not_move_the_calibration():
    # 40 dB noise and no sensor error at all. With the equations of motion alone the
    # calibration followed the noise: Ixz 3.8-4.3 % off, outside its interval. The rigid
    # fit's redundancy (estimator.redundancy) pins the gains and angles to what the
    # readings say, and the noise variance is taken from the calibrated residual.
    doc = run(
        I3,
        {"noise_snr_db": 40.0, "residual_unbalance_kgm": 5e-4, "seed": 3},
        estimator={"self_calibration": True},
    )
    errs = rel_errors(doc)
    assert max(abs(e) for e in errs.values()) < 0.005, errs
    assert np.all(cog_error_m(doc) < 0.001)


def test_two_sensors_cannot_self_calibrate():
    text = re.sub(r"\[\[sensors\]\]\nname = \"C_torque_rod\"\n(.+\n)+?\n", "", I3.read_text())
    assert '"C_torque_rod"' not in text
    bench = loads_bench(text + "\n[estimator]\nself_calibration = true\n", "two.toml")
    with pytest.raises(ConfigError, match=r"self_calibration: needs more than six.*has 6"):
        make_estimator(bench)
