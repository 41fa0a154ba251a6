"""The what-you-had / what-you-get rows: pairs, issue 44's targets, the Markdown."""

import math

from cvsss.core.eval.users_table import check_targets, format_table, format_targets, pairs


def _row(kind, engine="CYCLES", samples=16, denoise=True, variant="material", method="BURLEY",
         whole=30.0, sss=28.0, effect=25.0, rest=31.0, seconds=1.0, setup=0.2, steady=0.8):  # fmt: skip
    return {
        "kind": kind,
        "engine": engine,
        "samples": samples,
        "denoise": denoise,
        "variant": variant,
        "method": method,
        "frames": [1, 2],
        "mean": {
            "psnr_whole_db": whole,
            "psnr_subsurface_db": sss,
            "psnr_rest_db": rest,
            "effect_db": effect,
            "subsurface_share": 0.25,
        },
        "seconds_per_frame": seconds,
        "setup_seconds": setup,
        "steady_seconds_per_frame": steady,
        "post_method": "as_ccv",
    }


def _by_target(checks):
    return {c["target"]: c for c in checks}


def test_burley_targets_met_and_missed():
    rows = [
        _row("plain", sss=28.0, whole=30.0, seconds=1.0),
        _row("off", sss=20.0, whole=27.0),
        _row("apply_on_render", sss=29.5, whole=29.9, seconds=1.2),
    ]
    checks = _by_target(check_targets(rows))
    assert set(checks) == {
        "subsurface pixels >= plain + 1 dB",
        "whole frame >= plain",
        "time per frame <= 1.25 x plain",
    }
    sss = checks["subsurface pixels >= plain + 1 dB"]
    assert sss["met"] is True and sss["required"] == 29.0 and sss["why"] == []
    whole = checks["whole frame >= plain"]
    assert whole["met"] is False
    # Why: the figures beside it, the floor without subsurface included.
    assert any("outside the subsurface pixels (75.0 % of the frame)" in w for w in whole["why"])
    assert any("without subsurface: 20.00 dB" in w for w in whole["why"])
    assert checks["time per frame <= 1.25 x plain"]["met"] is True


def test_random_walk_time_miss_names_the_warm_up():
    rows = [
        _row("plain", method="RANDOM_WALK", variant="RANDOM_WALK", seconds=1.0, setup=0.3),
        _row(
            "apply_on_render",
            method="RANDOM_WALK",
            variant="RANDOM_WALK",
            seconds=4.0,
            setup=6.0,
            steady=1.0,
        ),  # fmt: skip
    ]
    checks = _by_target(check_targets(rows))
    time = checks["time per frame <= 1.25 x plain"]
    assert time["met"] is False and time["required"] == 1.25
    assert "Apply on Render 6.00 s" in time["why"][0] and "plain 0.30 s" in time["why"][0]
    assert checks["whole frame >= plain - 0.5 dB"]["met"] is True


def test_eevee_targets_use_the_effect_and_no_time():
    rows = [
        _row("plain", engine="EEVEE", denoise=False, effect=20.0, whole=22.0),
        _row("apply_on_render", engine="EEVEE", denoise=False, effect=20.5, whole=21.6),
    ]
    checks = _by_target(check_targets(rows))
    assert set(checks) == {
        "subsurface effect >= EEVEE's own + 1 dB",
        "whole frame >= EEVEE's own - 0.5 dB",
    }
    assert checks["subsurface effect >= EEVEE's own + 1 dB"]["met"] is False
    assert checks["whole frame >= EEVEE's own - 0.5 dB"]["met"] is True


def test_no_target_without_a_pair_or_the_denoiser_and_nan_is_not_a_verdict():
    assert check_targets([_row("plain")]) == []
    undenoised = [_row("plain", denoise=False), _row("apply_on_render", denoise=False)]
    assert check_targets(undenoised) == []
    # Different settings do not pair.
    assert pairs([_row("plain", samples=16), _row("apply_on_render", samples=64)]) == []
    rows = [_row("plain", sss=float("nan")), _row("apply_on_render")]
    sss = _by_target(check_targets(rows))["subsurface pixels >= plain + 1 dB"]
    assert sss["met"] is None and math.isnan(sss["required"])


def test_markdown():
    rows = [
        _row("apply_on_render", sss=29.5, whole=29.0),
        _row("plain"),
        _row("off", effect=float("nan")),
    ]
    table = format_table(rows, scene="flash").splitlines()
    assert table[0].startswith("| scene | setting | what |")
    assert len(table) == 5
    # Plain first, then what you get, then the floor; a missing figure is a dash.
    assert "| plain |" in table[2] and "Apply on Render (as_ccv)" in table[3]
    assert "without subsurface" in table[4] and "| – |" in table[4]
    assert "Cycles 16 spp + denoiser, Christensen-Burley (the materials' own)" in table[2]
    assert "1.00 (0.80)" in table[2]
    text = format_targets(check_targets(rows))
    assert "MISSED" in text and "met" in text and "  - outside" in text
