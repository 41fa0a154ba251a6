"""The quality knob: parsing, interpolation of the calibration, the shipped file.

Whether the knob delivers what it promises on real sequences (asking for
45 dB yields 45 ± 2 dB) is measured by ``cvsss bench`` and reported in
bench.json (``targets.quality_45db_error_db``): the calibration is not
resolution independent (PSNR at fixed spp drops ~4 dB from 160×90 to
320×180 on the bench scene), so a small test sequence cannot check it.
"""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from cvsss.core.eval import quality
from cvsss.core.eval.quality import Calibration, QualityTarget, choose, parse_quality
from cvsss.core.params import SSSParams


def _calibration() -> Calibration:
    """Two β_min families of as_ccv with round numbers, plus fixed."""
    return Calibration.from_dict(
        quality.calibration_dict(
            {
                "as_ccv": [
                    {
                        "param": "target_variance",
                        "values": [1e-4, 1e-3, 1e-2],
                        "psnr_db": [54.0, 50.0, 48.0],
                        "spp": [14.0, 10.0, 8.0],
                        "fixed": {"beta_min": 8},
                    },
                    {
                        "param": "target_variance",
                        "values": [1e-3, 1e-2],
                        "psnr_db": [47.0, 43.0],
                        "spp": [6.0, 2.0],
                        "fixed": {"beta_min": 2},
                    },
                ],
                "fixed": [
                    {
                        "param": "fixed_spp",
                        "values": [4, 16, 64],
                        "psnr_db": [45.0, 51.0, 57.0],
                        "spp": [4.0, 16.0, 64.0],
                        "fixed": {},
                    },
                ],
            },
            {"scene": "test", "resolution": "8x8", "frames": 1},
        )
    )


@pytest.mark.parametrize(
    ("text", "kind", "value"),
    [
        ("45dB", "psnr", 45.0),
        ("45 dB", "psnr", 45.0),
        ("47.5db", "psnr", 47.5),
        ("24spp", "spp", 24.0),
        (" 8 SPP ", "spp", 8.0),
        ("1e1spp", "spp", 10.0),
    ],
)
def test_parse_quality_known_values(text, kind, value):
    assert parse_quality(text) == QualityTarget(kind, value)


@pytest.mark.parametrize(
    "text",
    ["", "45", "dB", "45 dB spp", "-3dB", "0spp", "nan dB", "200dB", "5000spp", "45 decibel"],
)
def test_parse_quality_refuses_bad_text(text):
    with pytest.raises(ValueError, match="quality"):
        parse_quality(text)


def test_quality_target_checks_its_fields():
    with pytest.raises(ValueError, match="kind"):
        QualityTarget("ssim", 1.0)
    with pytest.raises(ValueError, match="value"):
        QualityTarget("psnr", math.inf)


def test_choose_interpolates_log_sigma_inside_the_paper_family():
    c = choose("52dB", "as_ccv", _calibration())
    # Halfway between 50 dB (1e-3) and 54 dB (1e-4) in dB ⇒ halfway in log10 σ0².
    assert c.changes == {"target_variance": pytest.approx(10**-3.5, rel=1e-3), "beta_min": 8}
    assert c.predicted_psnr_db == pytest.approx(52.0)
    assert c.predicted_spp == pytest.approx(12.0)
    assert not c.clamped


def test_choose_reproduces_calibrated_points_exactly():
    cal = _calibration()
    for s0, db in ((1e-4, 54.0), (1e-3, 50.0)):
        c = choose(QualityTarget("psnr", db), "as_ccv", cal)
        assert c.changes["target_variance"] == pytest.approx(s0, rel=1e-3)


def test_choose_lowers_beta_min_only_below_the_paper_floor():
    cal = _calibration()
    assert choose("48.5dB", "as_ccv", cal).changes["beta_min"] == 8
    low = choose("45dB", "as_ccv", cal)
    assert low.changes == {"target_variance": pytest.approx(10**-2.5, rel=1e-3), "beta_min": 2}
    assert low.predicted_spp == pytest.approx(4.0)


def test_choose_clamps_outside_every_family_and_says_so():
    cal = _calibration()
    high = choose("60dB", "as_ccv", cal)
    assert high.clamped and high.changes["target_variance"] == pytest.approx(1e-4)
    low = choose("30dB", "as_ccv", cal)
    assert low.clamped and low.changes == {"target_variance": pytest.approx(1e-2), "beta_min": 2}
    assert "outside the calibrated range" in low.describe()


def test_choose_spp_budget_buys_the_most_psnr_within_it():
    cal = _calibration()
    c = choose("12spp", "as_ccv", cal)
    assert c.changes["beta_min"] == 8
    assert c.changes["target_variance"] == pytest.approx(10**-3.5, rel=1e-3)
    assert choose("4spp", "as_ccv", cal).changes["beta_min"] == 2
    assert choose("100spp", "as_ccv", cal).clamped


def test_choose_is_monotone_in_the_target():
    cal = _calibration()
    sig = [
        choose(QualityTarget("psnr", db), "as_ccv", cal).changes["target_variance"]
        for db in np.linspace(48.0, 54.0, 13)
    ]
    assert all(a >= b for a, b in itertools.pairwise(sig))


def test_choose_fixed_picks_an_integer_n():
    c = choose("54dB", "fixed", _calibration())
    assert c.changes == {"fixed_spp": 32}


def test_choose_respects_a_user_beta_min_and_names_bad_input():
    cal = _calibration()
    assert choose("45dB", "as_ccv", cal, beta_min=8).clamped
    with pytest.raises(ValueError, match="beta_min=5"):
        choose("45dB", "as_ccv", cal, beta_min=5)
    with pytest.raises(ValueError, match="calibrated methods"):
        choose("45dB", "reference", cal)


def test_choose_survives_noisy_non_monotone_measurements():
    cal = Calibration.from_dict(
        quality.calibration_dict(
            {
                "as": [
                    {
                        "param": "target_variance",
                        "values": [1e-2, 1e-3, 1e-4, 1e-5],
                        "psnr_db": [48.0, 51.0, 50.8, 53.0],
                        "spp": [8.0, 12.0, 11.0, 20.0],
                        "fixed": {"beta_min": 8},
                    },
                ]
            },
            {},
        )
    )
    c = choose("51dB", "as", cal)
    assert 1e-4 <= c.changes["target_variance"] <= 1e-3
    assert np.isfinite(c.predicted_spp)


def test_apply_returns_validated_params():
    params, choice = quality.apply(SSSParams(eta=0.3), "52dB", "as_ccv", _calibration())
    assert params.eta == 0.3 and params.beta_min == 8
    assert params.target_variance == choice.changes["target_variance"]


def test_load_calibration_errors_name_the_regenerating_command(tmp_path):
    with pytest.raises(FileNotFoundError, match="cvsss bench"):
        quality.load_calibration(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"version": quality.CALIBRATION_VERSION}))
    with pytest.raises(ValueError, match="cvsss bench"):
        quality.load_calibration(bad)
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"version": 0, "methods": {}}))
    with pytest.raises(ValueError, match="version"):
        quality.load_calibration(old)


def test_shipped_calibration_covers_the_adaptive_methods_and_is_sane():
    cal = quality.load_calibration()
    assert {"as", "as_ocv", "as_ccv", "fixed"} <= set(cal.methods)
    assert cal.source["command"] == quality.REGENERATE_COMMAND
    for name in ("as", "as_ocv", "as_ccv"):
        fams = cal.methods[name]
        assert any(f.fixed.get("beta_min") == 8 for f in fams)
        for f in fams:
            assert np.all(np.isfinite(f.psnr_db)) and np.all((f.psnr_db > 20) & (f.psnr_db < 100))
            assert np.all(f.spp >= f.fixed["beta_min"] - 1e-9)
            # Smaller σ0² never costs fewer samples by more than noise.
            assert f.spp[0] >= f.spp[-1]
        # The knob's documented range includes 45 dB and the paper-family range.
        choice = choose("45dB", name, cal)
        assert not choice.clamped
        assert abs(choice.predicted_psnr_db - 45.0) < 1e-6
