"""The trace report's conclusion and signature figure (issue #21, item 5), on a hand-made trace document: fast."""

from __future__ import annotations

import numpy as np

from thsa_control.report.trace import conclusion_table_html, plot_candidate_drops, plot_signature


def _param(v, unit="N m/N", held=False):
    return {"value": v, "unit": unit, "ci95": None if held else [0.9 * v, 1.1 * v], "held": held}


def _doc():
    err = {"motor_speed": {"rms": 10.0, "unit": "rad/s"}}
    err2 = {"motor_speed": {"rms": 2.0, "unit": "rad/s"}}
    added = [
        {"name": "noback_backlash", "parameters": {"noback.pawl_pitch": _param(0.1, "rad")}, "not_determined": [],
         "window_reduction": {"motor_speed": 0.8}, "error_before": err, "error_after": err2},
        {"name": "noback_quadrant_friction", "implied_by": "noback_backlash",
         "parameters": {"noback.mu_coulomb_pos": _param(0.0048, held=True)},
         "not_determined": [{"parameter": "noback.mu_coulomb_pos", "held_at": 0.0048, "unit": "N m/N",
                             "reason": "the light disk is never loaded"}],
         "window_reduction": {"motor_speed": 0.8}, "error_before": err, "error_after": err2},
    ]
    x = np.linspace(0, 0.04, 21)
    curve = {"centre": list(x), "mean": list(0.01 * np.sin(100 * x)), "sd": [0.01] * 21, "count": [50] * 21}
    return {"base_corrections": None, "effects_added": added, "unexplained": True,
            "residual_signature": {
                "structured": ["nut_position (repeated over passes)"], "base_like": [],
                "tests": [{"variable": "nut_position (repeated over passes)", "kind": "local", "p_value": 1e-9,
                           "significant": True, "peak_bin": [0.004, 0.006], "law": "dissipative (opposes the motion)"},
                          {"variable": "time (slow drift)", "kind": "drift", "p_value": 0.3, "significant": False}],
                "curves": {"nut_position": {**curve, "by_direction": {"extending": curve, "retracting": curve}},
                           "motor_angle": curve, "screw_angle": curve, "cross_correlation": {},
                           "segment_torque": {"time": [1.0, 1.1, 6.0, 6.1], "torque": [0.01, 0.012, -0.01, -0.008],
                                              "direction": [1.0, 1.0, -1.0, -1.0]},
                           "motor_current": curve}}}


def test_conclusion_table_names_the_implied_effect_and_what_was_held():
    """An effect pulled in by another one is a row of its own, named as implied, with the parameter the run did
    not determine and the value it was held at."""
    html = conclusion_table_html(_doc())
    assert "implied by noback_backlash" in html and "noback_quadrant_friction" in html
    assert "noback.mu_coulomb_pos held at 0.0048" in html
    assert "unexplained: <b>True</b>" in html and "nut_position (repeated over passes)" in html


def test_signature_figure_has_the_nine_panels_and_marks_the_position_test():
    """Binned by nut position per direction (with the position test's peak bin), by motor and screw angle, the
    redundant sensors, the per-segment torques against time, the residual against the current, the load cell and
    the LVDT in the holds (the load-cell drift test's data), and the current of comparable passes (the torque
    constant's drift; here not tested, and the panel says so)."""
    fig = plot_signature(_doc()["residual_signature"])
    axes = fig.get_axes()
    assert len(axes) == 9
    titles = [a.get_title() for a in axes]
    kt = axes[titles.index(next(t for t in titles if "comparable passes" in t))]
    assert any("not tested" in t.get_text() for t in kt.texts)
    assert any("nut position" in t for t in titles) and any("slow drift" in t for t in titles)
    assert any("motor current" in t for t in titles)
    assert any("load cell in the holds" in t for t in titles) and any("LVDT in the holds" in t for t in titles)
    pos = axes[titles.index(next(t for t in titles if "nut position" in t))]
    labels = pos.get_legend_handles_labels()[1]
    assert any(lb.startswith("extending") for lb in labels) and any(lb.startswith("retracting") for lb in labels)
    assert "p 1e-09" in pos.get_title() and "dissipative" in pos.get_title()  # under the title: no legend covers it


def test_the_angle_panels_say_the_test_beyond_an_added_effects_harmonic_and_the_breakaway_sits_under_the_title():
    """The screw-angle panel of a model with a ripple says its test is beyond the ripple's harmonic and what is left
    there (the panel shows the leftover, so the reader sees why it is not flagged); the motor-angle panel gives its
    plain p-value; the breakaway test's line is under the nut-position title, where no legend covers it."""
    sig = _doc()["residual_signature"]
    sig["tests"] += [
        {"variable": "screw_angle", "kind": "periodic", "p_value": 0.025, "significant": False, "beyond_added": [1],
         "added_shapes": {"screw_friction_ripple": {"harmonic": 1, "amplitude": 0.0041, "p_value": 4e-28,
                                                    "significant": True, "fitted_amplitude": 0.050}}},
        {"variable": "motor_angle", "kind": "periodic", "p_value": 3e-9, "significant": True},
        {"variable": "nut_position (breakaway)", "kind": "breakaway", "p_value": 3.4e-7, "significant": True,
         "places": [{"position": 0.0}, {"position": 0.02}], "peak_position": 0.0, "peak_deviation": 0.24}]
    titles = [a.get_title() for a in plot_signature(sig).get_axes()]
    screw = next(t for t in titles if "screw angle" in t)
    assert "beyond screw_friction_ripple (harmonic 1): p 0.025" in screw and "8 % of the fitted" in screw, screw
    assert "STRUCTURED" not in screw
    assert "harmonics: p 3e-09 (STRUCTURED)" in next(t for t in titles if "motor angle" in t)
    pos = next(t for t in titles if "nut position" in t)
    assert "breakaway current at starts/reversals: p 3.4e-07 (STRUCTURED)" in pos and "+0.24 A at 0.0 mm" in pos, pos


def test_the_candidate_bar_chart_ticks_fall_on_decades_even_when_every_drop_is_tiny():
    """A round whose drops all sit inside the symmetric log's linear part (|drop| < 10) gets the ticks -10, 0, 10,
    not the data's own ends (once printed as "-2.43583e-1"); a round with large drops keeps its decades."""
    cand = lambda n, d, sig=False: {"name": n, "holdout_chi2_drop": d, "significant": sig, "plausible": True}
    doc = {"rounds": [{"round": 1, "model": [], "candidates": [cand("a", -0.243583), cand("b", 0.7), cand("c", 3.1)]},
                      {"round": 2, "model": ["c"], "candidates": [cand("a", -2e4), cand("b", 5e5, True)]}],
           "effects_added": [{"name": "b"}]}
    fig = plot_candidate_drops(doc)
    fig.canvas.draw()
    for ax in fig.get_axes():
        ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
        assert 0.0 in ticks and len(ticks) >= 3, ticks
        for t in ticks:  # 0 or a signed power of ten
            assert t == 0.0 or abs(np.log10(abs(t)) - round(np.log10(abs(t)))) < 1e-9, ticks
    assert max(fig.get_axes()[1].get_xticks()) >= 1e5
