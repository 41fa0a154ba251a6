"""float16 history: the scaled storage, its underflow remedy, and its drift from float32.

Remedy (core.history): in float16 the covariances are stored as Σ/η_cv and
the tracked variance as σ²/σ0². Without the scales the paper's η_cv = 1e-6
flushes every Σ to zero (the online CV silently becomes α = 1), and σ0² at
the limits of its range (1e-12 underflows, 1e6 overflows 65504) drives the
counts to β_min. The full measurement is ``cvsss fp16 --out out`` (300 flash frames at
96x54); these tests run it smaller.
"""

from __future__ import annotations

import numpy as np
import pytest

from cvsss.core.io import checkpoint
from cvsss.core.mc.history import History
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.studies import fp16
from cvsss.core.synthetic import scene_frame

HALF_ULP = 2.0**-11  # float16 relative rounding


def test_sigma_at_paper_eta_cv_underflows_without_scaling():
    eta_cv = 1e-6
    dz = np.linspace(1e-3, 0.15, 200)  # luminance deviations of a lit scene
    sigma = eta_cv * (1 - eta_cv) * dz * dz  # Σ after one EMCM step from Σ_0 = 0
    idx = np.arange(dz.size)
    raw = History.empty((1, dz.size), "float16", eta_cv, scaled=False)
    raw.write("syy", idx, sigma)
    assert np.all(raw.read("syy", idx) == 0.0)  # every value flushed to zero
    scaled = History.empty((1, dz.size), "float16", eta_cv)
    assert scaled.cov_scale == pytest.approx(1e6)
    scaled.write("syy", idx, sigma)
    back = scaled.read("syy", idx)
    assert np.all(back > 0)
    # Below float16's smallest normal (6.1e-5) the spacing is 6e-8 absolute.
    np.testing.assert_allclose(back, sigma, rtol=HALF_ULP, atol=3e-8 * eta_cv)


@pytest.mark.parametrize("s0", [1e-12, 1e-4, 1e6])
def test_variance_stored_relative_to_target(s0):
    ratios = np.array([1e-3, 0.5, 1.0, 2.0, 100.0, 3e4])
    idx = np.arange(ratios.size)
    h = History.empty((1, ratios.size), "float16", 1e-6, s0)
    h.write("var", idx, ratios * s0)
    np.testing.assert_allclose(h.read("var", idx), ratios * s0, rtol=HALF_ULP)
    # The no-history value σ² = σ0² is stored exactly (ratio 1).
    assert h.buffers["var"].reshape(-1)[2] == 1.0
    raw = History.empty((1, ratios.size), "float16", 1e-6, s0, scaled=False)
    raw.write("var", idx, ratios * s0)
    got = raw.read("var", idx)
    if s0 == 1e-12:
        assert np.all(got[ratios <= 100] == 0.0)  # underflow
    elif s0 == 1e6:
        assert np.all(got <= 65504.0)  # overflow, clipped: ratio ≤ 0.066


def test_float32_storage_is_never_scaled():
    h = History.empty((2, 2), "float32", 1e-6, 1e-12)
    assert h.cov_scale == 1.0 and h.var_scale == 1.0


def test_saturated_ratio_still_asks_for_beta_max():
    # A stored ratio clipped at 65504 must not lower the count below β_max.
    from cvsss.core.mc.adaptive import sample_counts

    p = SSSParams(target_variance=1e-12, beta_min=1, beta_max=4096)
    h = History.empty((1, 1), "float16", p.eta_cv, p.target_variance)
    h.write("var", np.array([0]), np.array([1.0]))  # ratio 1e12 -> 65504
    m = sample_counts(h.read("var", [0]), np.array([1.0]), np.array([True]), np.array([1.0]), p)
    assert m[0] == 4096


def test_checkpoint_round_trip_keeps_scales(tmp_path):
    proc = make_processor("as_ocv", SSSParams(history_precision="float16", target_variance=1e-8))
    for n in range(1, 4):
        proc.process(scene_frame("flash", n, 24, 16))
    h = proc.history
    path = tmp_path / "h.npz"
    checkpoint.save(path, {"method": "as_ocv"}, proc.state())
    state, arrays = checkpoint.load(path)
    assert state["method"] == "as_ocv"
    back = History.from_arrays(arrays, "h_")
    assert back.var_scale == h.var_scale == pytest.approx(1e8)
    assert back.cov_scale == h.cov_scale
    for key in h.buffers:
        assert back.buffers[key].dtype == np.float16
        assert np.array_equal(back.buffers[key], h.buffers[key])
    # A checkpoint written before σ² was scaled loads with var_scale 1.
    arrays = {k: v for k, v in h.to_arrays().items() if k != "var_scale"}
    assert History.from_arrays(arrays).var_scale == 1.0
    assert not list(tmp_path.glob("*.tmp-*"))


@pytest.fixture(scope="module")
def flash300():
    return [scene_frame("flash", n, 48, 27) for n in range(1, 301)]


def test_drift_over_300_flashing_frames(flash300):
    d = fp16.drift(flash300, "as_ocv", SSSParams())
    s16, raw = d["summary"]["float16"], d["summary"]["float16_unscaled"]
    # Scaled float16 follows float32: counts differ on well under 1 % of
    # pixel-frames, mean spp within 1 %, α within 1e-3 on average.
    assert abs(s16["spp_rel_diff"]) < 0.01
    assert s16["spp_rel_diff_max_frame"] < 0.05
    assert s16["dcount_share"] < 0.01
    assert s16["dalpha_mean"] < 1e-3 and s16["dalpha_max"] < 0.05
    assert s16["syy_significant_lost_share"] == 0.0
    # ... and does not drift away over the sequence.
    assert s16["dcount_mean_last_third"] < 0.05
    # Unscaled float16 loses every covariance: the online CV degenerates to α = 1
    # (ε_α/ε_α), cut below 1 only by the bound D = [0, (f̄ + ḡ)/ḡ] on the rare
    # pixel-frames whose distant estimate f̄ dips below 0.
    assert raw["syy_stored_zero_share"] == 1.0
    assert raw["syy_significant_lost_share"] == 1.0
    assert raw["alpha_mean_float16"] == pytest.approx(1.0, abs=1e-5)
    assert d["history_bytes"]["float16"] * 2 == d["history_bytes"]["float32"]


def test_variance_scaling_remedy(flash300):
    # ε_u = 0 so that every SSS pixel samples: β_min everywhere is then 8.0 spp (and the
    # paper's cold start n_init = β_min, so the first frames do not lift the mean).
    rows = fp16.variance_scaling(flash300[:30], SSSParams(eps_u=0.0, n_init=8))
    base = rows["0.0001"]["float32"]
    for s0, row in rows.items():
        # Exposure ∝ σ0 leaves the counts unchanged in exact arithmetic ...
        assert row["float32"] == pytest.approx(base, rel=0.01), s0
        assert row["float16"] == pytest.approx(base, rel=0.02), s0
    # ... but unscaled half storage breaks at both ends of σ0²'s range.
    assert base > 9.0
    assert rows["1e-12"]["float16_unscaled"] == 8.0
    assert rows["1e+06"]["float16_unscaled"] == 8.0
