"""The drive train's torsional mode read off a record: the ringing between the motor-speed and screw-speed sensors.

With the rotor speed ``w_m`` imposed (a speed-controlled motor), the gear-output side of a compliant drive train
follows it through ``w_o / w_m = (c s + k') / (J s^2 + c s + k')`` (``k' = eta k``, :func:`~thsa_control.model.laws.
drivetrain_modes`), so the twist rate ``r = w_m - N w_screw`` over the motor speed is

    H(s) = J s^2 / (J s^2 + c s + k'):

nothing at low frequency, a resonance of gain about ``1 / (2 zeta)`` at the gear-output mode, 1 above it.  Whatever
drives the motor speed (a chirp, steps, reversals, the controller's own ripple), ``H`` is estimated from the
record's cross-spectrum (``S_wr / S_ww``, Welch) and the coherence says where the twist rate is the motor speed's
response and not noise.  A lightly damped mode is a peak of ``|H|`` well above 1 where the two are coherent; what
else the two sensors can disagree by has another shape: a gain error on one sensor a flat ``|H|`` (the error), a
lag on one a ``|H|`` that rises with frequency, resolver noise an incoherent ``|H|``.

The tracer's drive-train compliance candidate starts its stiffness at the mode found here
(:func:`drivetrain_resonance_start`): the fit's cost has a minimum at each stiffness whose ringing matches the
record's in some phase, and started at the parameter file's stiffness (a mode near 87 Hz) on rig-sim's speed
excitation with a 47 Hz mode, it stopped at the wrong one (docs/trace_notes.md).  Where the record shows no
such peak, nothing is returned and the candidate starts at the file's values as before.

Imports numpy and scipy; no plotting, no file parsing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..model.laws import drivetrain_modes, drivetrain_stiffness, stiffness_of_output_mode
from ..model.params import ParameterSet

__all__ = ["twist_resonance", "drivetrain_resonance_start", "MIN_PEAK_GAIN", "MIN_COHERENCE", "PEAK_RISE"]

#: Least gain of the twist rate over the motor speed at the peak: a mode damped at most ``1 / (2 x 5) = 0.1`` of
#: critical.  Measured on the committed and fresh rig-sim records (500 Hz): the drive-train compliance records
#: (rig-sim's 8000 N m/rad, 2 N m s/rad, a mode near 47 Hz) peak at 9-19; where the two speeds are coherent
#: (coherence >= 0.5) no null or other effect exceeds 4.1 (rig-sim's 20 ms lag on the motor-speed sensor, rising to 4.1 at
#: 35 Hz)
MIN_PEAK_GAIN = 5.0
#: Least coherence of twist rate and motor speed at the peak (the twist is the motor speed's response there, not
#: noise); the compliance records have 0.62-0.99 at their peak
MIN_COHERENCE = 0.5
#: The peak must rise by this factor from ``f / 1.5`` (a resonance: ``|H|`` grows as
#: ``(f/f_n)^2`` below it, 0.8 at ``f_n / 1.5``, against 1 / (2 zeta) at it): a lag's ``|H|``, which rises
#: steadily with frequency, rises by 1.5 over the same span
PEAK_RISE = 2.0
#: Highest frequency searched, as a fraction of the sample rate: the speed sensors' difference quotients (over one
#: or two samples) differ above it, and their difference is itself a rising ``|H|``
MAX_FRACTION_OF_RATE = 0.3
#: Welch segment length [s]: 2 Hz resolution (a mode at 47 Hz placed within 2 %, its stiffness within 4 %)
SEGMENT_S = 0.5


def twist_resonance(runs: Sequence, band_hz: tuple[float, float] = (5.0, math.inf)) -> dict | None:
    """The strongest lightly damped mode of the twist rate over the motor speed in ``band_hz`` over ``runs`` (each
    with a motor-speed and a screw-speed sensor; the others are skipped): ``{"frequency_hz", "gain", "coherence",
    "run", "band_hz"}``, or None when no run shows one (see the module notes for the tests)."""
    from scipy import signal

    best = None
    for run in runs:
        cols = getattr(run, "source_columns", ())
        if "motor_speed" not in cols or "screw_speed" not in cols:
            continue
        t = np.asarray(run.time, float)
        w = np.asarray(run.signals["motor_speed"], float)
        r = w - run.gear_ratio * np.asarray(run.signals["screw_speed"], float)
        ok = np.isfinite(w) & np.isfinite(r)
        if ok.sum() < 64:
            continue
        # the longest stretch of finite samples (a dropout splits a record; Welch needs a regular sequence)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
        a, b = max(zip(edges[::2], edges[1::2]), key=lambda e: e[1] - e[0])
        dt = np.diff(t[a:b])
        if dt.size < 63 or not np.all(dt > 0) or np.ptp(dt) > 1e-3 * np.median(dt):
            continue  # irregular sampling: no spectrum
        fs = 1.0 / float(np.median(dt))
        nper = max(64, int(2 ** round(math.log2(SEGMENT_S * fs))))
        if b - a < 4 * nper:
            continue  # fewer than 4 segments (7 with the half overlap): no estimate to trust
        f, sww = signal.welch(w[a:b], fs, nperseg=nper)
        _, swr = signal.csd(w[a:b], r[a:b], fs, nperseg=nper)
        _, srr = signal.welch(r[a:b], fs, nperseg=nper)
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.abs(swr) / sww
            coh = np.abs(swr) ** 2 / (sww * srr)
        lo, hi = band_hz[0], min(band_hz[1], MAX_FRACTION_OF_RATE * fs)
        for i in range(1, f.size - 1):
            if not (lo <= f[i] <= hi and np.isfinite(gain[i]) and gain[i] >= MIN_PEAK_GAIN
                    and coh[i] >= MIN_COHERENCE and gain[i] >= gain[i - 1] and gain[i] >= gain[i + 1]):
                continue
            below = float(np.interp(f[i] / 1.5, f, gain))
            if not gain[i] >= PEAK_RISE * below:
                continue
            if best is None or gain[i] > best["gain"]:
                best = {"frequency_hz": float(f[i]), "gain": float(gain[i]), "coherence": float(coh[i]),
                        "run": getattr(run, "name", ""), "band_hz": [float(lo), float(hi)]}
    return best


def drivetrain_resonance_start(params: ParameterSet, runs: Sequence, found: dict | None = None) -> dict[str, float]:
    """The gearbox torsional stiffness whose gear-output mode (:func:`~thsa_control.model.laws.drivetrain_modes`,
    the plant's own inertias at ``params``, the screw's stiffness held in series) is the one the runs ring at
    (:func:`twist_resonance`, searched over the modes of the parameter's range); ``{}`` when they show none, or
    when the mode asks a stiffness the screw's alone cannot give (then the file's start stands).  ``found``, when
    given, receives :func:`twist_resonance`'s result."""
    from ..model import build_plant

    name = "gear.torsional_stiffness"
    plant = build_plant("A", ["drivetrain_compliance"], params=params)
    j_main, j_rotors = plant.inertia(params)
    eta, ratio2 = params.value("gear.efficiency"), params.value("gear.ratio") ** 2

    def mode_hz(k_gear: float) -> float:
        k = drivetrain_stiffness({**{n: params.value(n) for n in ("screw.torsional_stiffness", "gear.ratio")},
                                  name: k_gear})
        return drivetrain_modes(k, j_main, j_rotors, eta)[1] / (2 * math.pi)

    mode = twist_resonance(runs, (mode_hz(params[name].min), mode_hz(params[name].max)))
    if mode is None:
        return {}
    if found is not None:
        found.update(mode)
    series = stiffness_of_output_mode(2 * math.pi * mode["frequency_hz"], j_main, eta) * ratio2
    k_screw = params.value("screw.torsional_stiffness")
    if series >= k_screw:
        return {}
    return {name: 1.0 / (1.0 / series - 1.0 / k_screw)}
