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


def test_a_missed_target_is_split_by_object():
    plain, ours = _row("plain", sss=30.0), _row("apply_on_render", sss=30.5)
    # Squared errors summed over each object's subsurface pixels: PSNR = -10 log10(sse / n).
    plain["objects"] = {
        "Top": {
            "pixels": 100,
            "display_sse": 0.1,
            "effect_sse": 0.4,
        },  # 30 dB, 80 % of plain's (effect 23.98)
        "Suzanne": {"pixels": 10, "display_sse": 0.02, "effect_sse": 0.01},  # 26.99 dB, 16 %
        "": {"pixels": 5, "display_sse": 0.005, "effect_sse": 0.0},  # 30 dB, 4 %
    }
    ours["objects"] = {
        "Top": {"pixels": 100, "display_sse": 0.05, "effect_sse": 0.1},  # 33.01 dB (effect 30)
        "Suzanne": {"pixels": 10, "display_sse": 0.04, "effect_sse": 0.01},  # 23.98 dB
        "": {"pixels": 5, "display_sse": 0.005, "effect_sse": 0.0},
    }
    ours["cycles_renders"] = ["Suzanne"]
    (check,) = (c for c in check_targets([plain, ours]) if c["target"].startswith("subsurface"))
    assert check["met"] is False
    text = format_targets([check])
    lines = text.splitlines()
    start = lines.index(
        "  - by object, the frame on its subsurface pixels (plain → Apply on Render):"
    )
    assert lines[start + 1 :] == [
        "    - Top: 30.00 → 33.01 dB on 100 pixels (80.0 % of plain's squared error)",
        "    - Suzanne (Cycles renders its subsurface): 26.99 → 23.98 dB on 10 pixels"
        " (16.0 % of plain's squared error)",
        "    - (no object): 30.00 → 30.00 dB on 5 pixels (4.0 % of plain's squared error)",
    ]
    # The effect's target reads the effect's sums; a zero error is the PSNR cap.
    eevee = [dict(r, engine="EEVEE", samples=16) for r in (plain, ours)]
    (effect,) = (c for c in check_targets(eevee) if c["target"].startswith("subsurface effect"))
    assert "    - Top: 23.98 → 30.00 dB on 100 pixels (97.6 % of plain's squared error)" in (
        format_targets([effect]).splitlines()
    )
    assert "    - (no object): 100.00 → 100.00 dB on 5 pixels (0.0 % of plain's squared error)" in (
        format_targets([effect]).splitlines()
    )
    # Rows without the split (an older report) say nothing more.
    for row in (plain, ours):
        del row["objects"]
    (check,) = (c for c in check_targets([plain, ours]) if c["target"].startswith("subsurface"))
    assert not any("by object" in why for why in check["why"])
