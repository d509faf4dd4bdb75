"""The tracer's candidates: which effects it may add, where each acts, and how large it may plausibly be.

Owns the documented default uncertain parameters of each level (:data:`DEFAULT_UNCERTAIN`), the live
view of the effect registry's candidate specs (:data:`CANDIDATES`, :func:`not_candidates`,
:func:`candidate_specs`), the plausible magnitudes (:data:`PLAUSIBLE`) and the base correction's
efficiency explainer (:data:`EFFICIENCY_EXPLAINER`), and the windows a candidate acts in
(:data:`WINDOWS`, :func:`_window`).  Used by :mod:`thsa_control.trace.engine`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..data.rigdata import RigRun, measured_motor_speed, motion_sign, speed_integral, stop_band
from ..fit.residuals import reversal_proximity
from ..model import EFFECTS, CandidateSpec
from ..model.params import ParameterSet
from .signature import motion_band, sustained_motion

#: The documented default uncertain parameters of each level (fitted before any candidate).
#: The efficiencies are held at the parameter file's values by default: with a
#: constant force on the nut, free efficiencies make a direction-dependent
#: torque that stands in for any missing friction (and, at the papers' loads,
#: a self-locking screw for a missing no-back); free them with ``uncertain``.
DEFAULT_UNCERTAIN: dict[str, tuple[str, ...]] = {
    "A": ("gear.viscous_friction",),
    "B": ("gear.viscous_friction", "noback.mu_coulomb_pos", "noback.mu_coulomb_neg"),
}
DEFAULT_UNCERTAIN["C"] = DEFAULT_UNCERTAIN["B"]
DEFAULT_UNCERTAIN["D"] = DEFAULT_UNCERTAIN["B"]


class _CandidateView(Mapping):
    """The registered effects' tracer candidate specs by name (a live view of the registry).

    Each effect declares its spec (or why it is not a candidate) with its other
    knowledge (:class:`~thsa_control.model.Effect`); this view lists the specs.
    """

    def __getitem__(self, name: str) -> CandidateSpec:
        spec = EFFECTS[name].candidate if name in EFFECTS else None
        if not isinstance(spec, CandidateSpec):
            raise KeyError(name)
        return spec

    def __iter__(self):
        return (n for n, e in EFFECTS.items() if isinstance(e.candidate, CandidateSpec))

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: Candidate spec of every registered effect that is a candidate.
CANDIDATES: Mapping[str, CandidateSpec] = _CandidateView()


def not_candidates() -> tuple[str, ...]:
    """Effects that are configurations or faults, not candidates of a healthy rig's residual.

    Each says why (``Effect.candidate`` is a :class:`~thsa_control.model.NotCandidate`): the fault
    effects (a jam, a load-path failure, the end stops, the limiter's slip, the motor brakes) act
    through an event or a threshold that gives a fit no gradient on data where they do not fire.
    Name one in ``candidates`` to score it anyway.
    """
    return tuple(n for n, e in EFFECTS.items() if not isinstance(e.candidate, CandidateSpec))


#: The base correction's efficiency explainer: not an effect but the declared ball screw's efficiencies freed
#: within their plausible spread (the rig's screw may be a little better or worse than the file says; a
#: load-proportional drag while driving, such as a no-back that drags, is the same torque)
EFFICIENCY_EXPLAINER = CandidateSpec("efficiency", ("screw.efficiency_direct", "screw.efficiency_inverse"), {}, "loaded",
                                     base_correction=True, plausible={"screw.efficiency_direct": "efficiency",
                                                                      "screw.efficiency_inverse": "efficiency"})


#: The base correction's motor-side inertia explainer: not an effect but the declared rotor inertia freed within
#: what a rig's drive train adds at the motor shaft and the datasheet allows.  Level A's motor shaft carries the
#: rotors only; every real drive also turns a coupling and the gearbox's input stage at motor speed.  Measured on
#: rig-sim's speed excitation (its `rig` base adds a 4e-5 kg m^2 gear input stage, 11 % of two rotors): with the
#: file's inertia the motor-speed error the base leaves is 5.7 x its sensor noise, with rig-sim's 2.1 x, and that
#: error outweighed the screw speed in every candidate fit (docs/trace_notes.md, "Drive-train compliance: the
#: motor-side inertia").  Bounded in :func:`_rule_inertia`.
INERTIA_EXPLAINER = CandidateSpec("motor_side_inertia", ("motor.rotor_inertia",), {}, "moving",
                                  base_correction=True, plausible={"motor.rotor_inertia": "inertia"})

#: relative tolerance of a servo motor's catalogue rotor inertia (datasheets give the moment of inertia to
#: +-10 %): how far below the file's value the motor-side inertia may plausibly be
INERTIA_DATASHEET_TOLERANCE = 0.10
#: what a coupling and the gearbox's input stage add at the motor shaft, relative to the rotor inertia (assumed from
#: typical catalogue values, not from the papers, which give the rotor only):
#: two-stage planetary reductions for a 2 N m servo motor have 0.1-0.4 kg cm^2 at their input and bellows couplings
#: of that size 0.05-0.1 kg cm^2, against this rotor's 1.8 kg cm^2: up to 0.5 kg cm^2, 28 % (rig-sim assumes
#: 0.4 kg cm^2 for its pinion and first stage)
INERTIA_DRIVE_TRAIN_ADDITION = 0.28


def _rule_inertia(params: ParameterSet, runs) -> tuple[float, str]:
    j = params.value("motor.rotor_inertia")
    return INERTIA_DRIVE_TRAIN_ADDITION, (
        f"-{INERTIA_DATASHEET_TOLERANCE:.0%} .. +{INERTIA_DRIVE_TRAIN_ADDITION:.0%} of the parameter file's rotor "
        f"inertia ({j:.3g} kg m^2 per motor): a servo-motor datasheet's +-10 % tolerance below, and above it what a "
        "coupling and a two-stage gearbox's input stage add at the motor shaft (assumed from typical catalogue values: "
        "0.15-0.5 kg cm^2 for a 2 N m motor's drive train, against a 1.8 kg cm^2 rotor); level A's motor shaft carries "
        "the rotors only")


def _rule_drag(params: ParameterSet, runs) -> tuple[float, str]:
    t = 0.03 * params.value("motor.rated_torque")
    return t, (f"3 % of motor.rated_torque ({params.value('motor.rated_torque'):g} N m) = {t:.3g} N m at the motor shaft: "
               "a healthy drive's no-load drag is about 2 % of rated torque (the parameter file's gear.viscous_friction "
               "source), with half as much again for a rig's seals and bearings")


def _rule_axial(params: ParameterSet, runs) -> tuple[float, str]:
    fmax = max((float(np.nanmax(np.abs(np.asarray(r.signals["load_force"], float)))) for r in runs), default=0.0)
    f = 100.0 + 0.01 * fmax
    return f, (f"100 N + 1 % of the largest measured load ({fmax:.0f} N) = {f:.0f} N: a load cell calibrated to 1 % of "
               "the range the rig uses plus 100 N of fixture weight and seal drag; an axial force of kilonewtons the "
               "load cell does not see is not a rig's base but an effect")


def _rule_periodic(params: ParameterSet, runs) -> tuple[float, str]:
    t = 0.05 * params.value("motor.rated_torque")
    return t, (f"5 % of motor.rated_torque = {t:.3g} N m amplitude at the motor shaft: servo-motor cogging and ball-screw "
               "friction ripple are a few per cent of rated torque (catalogue cogging below 2 %)")


#: spread of a two-stage reduction's efficiency around the file's assumed 0.95 (0.93..0.97: 0.98..0.985 per stage,
#: catalogue values of spur and planetary stages); the gearbox efficiency is not freed (in a steady motion only the
#: product with the screw's shows), so the screw's efficiency explainer carries it
GEAR_EFFICIENCY_SPREAD = 0.02


def _rule_efficiency(params: ParameterSet, runs) -> tuple[float, str]:
    es, eg = params.value("screw.efficiency_direct"), params.value("gear.efficiency")
    gear = es * GEAR_EFFICIENCY_SPREAD / eg
    b = 0.05 + gear
    return b, (f"+-{b:.3f} around the parameter file's efficiency: 0.05, the spread of catalogue ball-screw "
               f"efficiencies at one lead and diameter, plus {gear:.3f}, the gearbox's +-{GEAR_EFFICIENCY_SPREAD:g} "
               f"around its assumed {eg:g} (two-stage reductions 0.93..0.97) carried by the screw's efficiency "
               f"(x {es:g}/{eg:g}; only the product shows in a steady motion); a no-back's load-proportional drag "
               "while driven also shows as a direct-efficiency loss and is not covered beyond this")


#: The no-back's static disk coefficients [N m/N] and the load sign that makes each one's disk set the loaded one
#: (``noback_quadrant_friction``: the compressive-side set, locked against retraction, carries a compressive load,
#: the tensile-side set a tensile one): a value the run determines below the holding limit (:func:`_rule_holding`)
#: for a set the run loads is a no-back that does not hold, no rig's base
HOLDING_COEFFICIENTS = {"noback.mu_static_neg": +1.0, "noback.mu_static_pos": -1.0}
#: samples beyond the light set's unloading for a disk set to count as loaded by the runs
HOLDING_MIN_SAMPLES = 50


#: moving samples (speed above this share of the record's largest) with the load inside the no-back's band (below
#: the light set's unloading at the file's preload and share) for the runs to say anything of the preload
BAND_MOVING_FRACTION = 0.05


def noback_unloading_loads(params: ParameterSet) -> tuple[float, float]:
    """``(compressive, tensile)`` load [N] beyond which the no-back's light disk set is unloaded and the loaded one
    carries the whole load, at the parameter file's preload and load share."""
    pre, share = params.value("noback.preload"), params.value("noback.load_share")
    return pre / max(1.0 - share, 1e-9), pre / max(share, 1e-9)


def noback_band_gate(params: ParameterSet, runs) -> str | None:
    """None where the runs move with the load inside the band where both no-back disk sets carry load (at least
    :data:`HOLDING_MIN_SAMPLES` such samples, at the file's preload and share), else why the preload is not freed.
    Outside that band the loaded set carries the load alone and the preload changes no moving sample; freed on
    rig-sim's two-magnitude sets anyway (10..30 kN, no moving sample below 6 kN) it took 864-1072 N from what the
    Coulomb drag or the axial force had carried, and neither was named."""
    comp, tens = noback_unloading_loads(params)
    k = 0
    for r in runs:
        sig = getattr(r, "signals", None) or {}
        if "load_force" not in sig or "motor_speed" not in sig:
            continue
        f, w = np.asarray(sig["load_force"], float), np.asarray(sig["motor_speed"], float)
        top = float(np.nanmax(np.abs(w))) if w.size else 0.0
        mov = np.abs(w) > BAND_MOVING_FRACTION * top if top > 0 else np.zeros(w.shape, bool)
        k += int(np.sum(mov & (f < comp) & (f > -tens)))
    if k >= HOLDING_MIN_SAMPLES:
        return None
    return (f"not freed: {k} moving samples with the load inside the band where both disk sets carry load (below "
            f"{comp:.0f} N compressive, {tens:.0f} N tensile at the file's preload and share; at least "
            f"{HOLDING_MIN_SAMPLES} needed): beyond it the loaded set carries the load alone and the preload changes "
            "no moving sample")


#: second-stage parameter -> ``gate(params, runs)``: None where the runs can inform it, else why it is held
SECOND_STAGE_GATES = {"noback.preload": noback_band_gate}


def _rule_holding(params: ParameterSet, runs) -> tuple[float, str, tuple[str, ...]]:
    """``(limit, source, coefficients)``: the holding limit [N m/N], where it comes from, and the static
    coefficients of the disk sets the runs load beyond the light set's unloading (the file's preload and load share:
    the loaded set then carries the whole load; below it both sets share the load and the preload helps hold)."""
    lead, eta = params.value("screw.lead"), params.value("screw.efficiency_inverse")
    mu = lead * eta / (2.0 * math.pi)
    unload = dict(zip((+1.0, -1.0), noback_unloading_loads(params)))  # compressive, tensile [N]
    loaded = []
    for n, sign in HOLDING_COEFFICIENTS.items():
        k = sum(int(np.sum(sign * np.asarray(r.signals["load_force"], float) > unload[sign])) for r in runs
                if "load_force" in r.signals)
        if k >= HOLDING_MIN_SAMPLES:
            loaded.append(n)
    return mu, (f"the holding limit lead x inverse efficiency / 2 pi = {lead * 1e3:g} mm x {eta:g} / 2 pi = "
                f"{mu:.3g} N m/N: beyond {unload[+1.0]:.0f} N compressive ({unload[-1.0]:.0f} N tensile) the loaded "
                "disk set carries the whole load, and with a static coefficient below this the load back-drives the "
                "screw through it; a no-back's function is to hold (the papers' Table 2 gives 0.0066 and 0.0072, four "
                "times the limit), so one that slips under the load it carries is a fault or another effect (a "
                "ratchet's free travel), not a rig's base"), tuple(loaded)


#: the largest damping ratio of the drive train's twist mode a gear train can have (:func:`_rule_damping_ratio`)
DAMPING_RATIO_LIMIT = 1.0


def _rule_damping_ratio(params: ParameterSet, runs) -> tuple[float, str]:
    """``(limit, source)``: the damping ratio of the drive train's twist mode above which a fitted compliance is no
    gear train (:func:`thsa_control.model.laws.drivetrain_damping_ratio`)."""
    return DAMPING_RATIO_LIMIT, (
        f"critical damping, a damping ratio of {DAMPING_RATIO_LIMIT:g}: a gear train's twist mode is lightly damped "
        "(assumed: gear-dynamics models use damping ratios of a few hundredths to about 0.2; the parameter file's 20 "
        "N m s/rad is 0.2; rig-sim's drive-train compliances were fitted at 0.01..0.37), and an overdamped one does "
        "not ring: the screw then follows the rotors as a first-order lag, which a lagging speed sensor gives too")


#: Plausible magnitudes (rule -> function(params, runs) -> (bound, where the bound comes from); ``holding`` adds the
#: coefficients it applies to on these runs).
PLAUSIBLE: dict[str, Callable] = {"drag": _rule_drag, "axial_force": _rule_axial, "periodic": _rule_periodic,
                                  "efficiency": _rule_efficiency, "inertia": _rule_inertia, "holding": _rule_holding,
                                  "damping_ratio": _rule_damping_ratio}


class ReadStart(dict):
    """Starting values read off the runs (name -> value) and, in ``why``, what they were read from."""

    def __init__(self, values=(), why: str = ""):
        super().__init__(values)
        self.why = why


def _start_loadpath(params: ParameterSet, runs) -> ReadStart:
    from ..fit.loadpath_screen import loadpath_static_screen

    return ReadStart(loadpath_static_screen(runs, params), "the static load-path deflection (the LVDT against the "
                     "kinematic nut position) against the measured load")


#: samples per cogging period for the period to count as resolved: the Nyquist limit is 2; 4 keeps the harmonic below
#: half the Nyquist frequency, where the model's one step per sample still follows it (its torque is evaluated once
#: per step: at 2 samples per period the steps alternate between two angles) and the speed sensor's difference
#: quotient over one sample keeps 90 % of its amplitude (sinc(1/4))
COGGING_SAMPLES_PER_PERIOD = 4.0


def turning_band(run: RigRun) -> float:
    """The motor speed [rad/s] beyond which the motor turns: ``MOTION_SIGMA`` noise standard deviations of the
    measured motor speed (:func:`motor_turning`, :func:`~thsa_control.trace.signature.motion_band`)."""
    return motion_band(measured_motor_speed(run))


def motor_turning(run: RigRun) -> np.ndarray:
    """Samples where the motor turns: the measured motor speed beyond ``MOTION_SIGMA`` noise standard deviations (a
    cogging torque is periodic in the motor angle, so it shows wherever the angle advances, however slowly: a
    position loop's creep at 2 % of the top speed is the motion that resolves it best; the ``moving`` window's 5 % of
    the largest speed leaves it out)."""
    w = np.nan_to_num(np.asarray(measured_motor_speed(run), float))
    return np.abs(w) > turning_band(run)


def cogging_resolved(run: RigRun, count: float, steady: bool = True, transient_time: float = 0.3) -> np.ndarray:
    """Samples where a cogging of ``count`` periods per motor revolution is resolved: the motor turns and the period
    spans ``COGGING_SAMPLES_PER_PERIOD`` samples or more (above it the record aliases the harmonic: at 15 mm/s the
    18th harmonic of rig-sim's motor speed is at 1.5 kHz); ``steady``: outside the base's transients, judged on the
    speed averaged over the transient time (:func:`~thsa_control.trace.signature.base_transients` with
    ``sustained``: the cogging ripples the speed itself, and its own ripple is no transient), its starts and stops also
    where the speed crosses the band the window calls motion (:func:`turning_band`: the end of a position loop's creep
    is a stop)."""
    return _cogging_resolver(run, steady, transient_time)(count)


def _cogging_resolver(run: RigRun, steady: bool = True, transient_time: float = 0.3) -> Callable:
    """``count -> `` :func:`cogging_resolved` ``(run, count, steady, transient_time)``: what does not depend on the
    count (the turning motor, the base's transients, the sample rate) computed once."""
    from .signature import base_transients

    t = np.asarray(run.time, float)
    if t.size < 2:
        return lambda count: np.zeros(t.shape, bool)
    fs = 1.0 / float(np.median(np.diff(t)))
    w = np.nan_to_num(np.asarray(measured_motor_speed(run), float))
    where = motor_turning(run)
    if steady:
        where &= ~base_transients(t, w, run.signals["load_force"], transient_time, sustained=True,
                                  motion_band=turning_band(run))
    return lambda count: where & (count * np.abs(w) / (2 * math.pi) * COGGING_SAMPLES_PER_PERIOD < fs)


def cogging_pole_count(params: ParameterSet) -> int:
    """The motor's pole count 2 p: a cogging's period count per revolution is the least common multiple of the slot
    count and the pole count (Zhu and Howe, IEEE Trans. Energy Convers. 15 (2000) 407; the parameter file's
    ``drive.cogging_periods`` description), hence a multiple of 2 p.  1 where the parameter set has no pole pairs."""
    return round(2 * params.value("motor.pole_pairs")) if "motor.pole_pairs" in params else 1


#: the largest phase uncertainty [rad] of a shooting segment's motor angle at which a cogging count is still fitted
#: as one torque of the motor angle: a sinusoid fitted over segments whose phases scatter by s keeps exp(-s^2 / 2) of
#: its amplitude (61 % at 1 rad); beyond it each segment picks its own phase through its free start position, and the
#: candidate is a free sinusoid per segment (measured on a position-loop null, 500 Hz: 78 per revolution, whose
#: period is 2.3 um of nut travel against the LVDT's 2 um noise, lowered the training error by an AIC of 347 and
#: raised the held-out error)
COGGING_PHASE_SCATTER = 1.0


def cogging_anchored_count(params: ParameterSet, runs, segment_duration: float) -> float:
    """The largest cogging count whose phase the record anchors in each shooting segment.  A segment's motor angle
    starts from its fitted nut position (``x / r``), which the LVDT determines to ``sigma / sqrt(m)`` over the
    segment's ``m`` samples; the count's period in nut travel, ``lead / (N n)``, must be at least ``2 pi / s`` times
    that (``s`` = :data:`COGGING_PHASE_SCATTER`).  Infinite without an LVDT reading (nothing to bound it by)."""
    from ..fit.identify import estimate_noise

    best = 0.0
    for r in runs:
        if not r.has("nut_position"):
            return math.inf
        x = np.asarray(r.signals["nut_position"], float)
        t = np.asarray(r.time, float)
        if not np.isfinite(x).any() or t.size < 2:
            return math.inf
        m = max(segment_duration * (1.0 / float(np.median(np.diff(t)))), 1.0)
        sigma = estimate_noise(x[np.isfinite(x)]) / math.sqrt(m)
        if not sigma > 0:
            return math.inf
        best = max(best, params.value("screw.lead") / params.value("gear.ratio") * COGGING_PHASE_SCATTER
                   / (2 * math.pi * sigma))
    return best


def cogging_counts(params: ParameterSet, runs, lo: float, hi: float, transient_time: float = 0.3,
                   segment_duration: float | None = None) -> tuple[list[float], str | None]:
    """The cogging period counts a record can resolve: the multiples of the pole count (:func:`cogging_pole_count`)
    within ``lo..hi`` whose resolved samples outside the base's transients (:func:`cogging_resolved`), over all runs,
    number ``MIN_WINDOW_SAMPLES`` or more (the fewest a candidate's window is scored on), and, with the fits'
    ``segment_duration``, whose phase the record anchors (:func:`cogging_anchored_count`).  Returns the counts and,
    where there is none, why the cogging cannot be resolved on this record."""
    step = cogging_pole_count(params)
    first = step * max(math.ceil(lo / step), 1)
    if segment_duration is not None:
        anchored = cogging_anchored_count(params, runs, segment_duration)
        hi = min(hi, anchored)
        if first > hi:
            return [], (f"cannot be resolved on this record: the LVDT anchors a segment's motor angle to a cogging "
                        f"count of {anchored:.3g} per revolution at most, below the lowest one ({first}, a multiple "
                        f"of the {step} poles)")
    resolved = [_cogging_resolver(r, transient_time=transient_time) for r in runs]  # the masks' parts, once a run
    counts = []
    for n in range(first, math.floor(hi) + 1, step):
        k = sum(int(res(n).sum()) for res in resolved)
        if k < MIN_WINDOW_SAMPLES:
            break  # fewer at every larger count
        counts.append(float(n))
    if counts:
        return counts, None
    k = sum(int(res(first).sum()) for res in resolved)
    return [], (f"cannot be resolved on this record: even the lowest cogging count ({first} per motor revolution, a "
                f"multiple of the {step} poles) spans {COGGING_SAMPLES_PER_PERIOD:g} samples per period on only {k} "
                f"samples where the motor turns outside the base's transients (fewer than {MIN_WINDOW_SAMPLES}): "
                "faster, the harmonic is aliased")


#: Profiled parameters whose search starts at a physical floor, not at an assumed edge: a value there is no sign of a
#: search range too narrow (the cogging's count is searched from the pole count up, and lcm(slots, 2 p) >= 2 p).
PROFILE_FLOORS: tuple[str, ...] = ("drive.cogging_periods",)

#: The values a profiled parameter is searched over where the record limits them (name -> function(params, runs, lo,
#: hi) -> (values, reason when there is none)): the cogging's period counts the record resolves.
PROFILE_GRIDS: dict[str, Callable] = {"drive.cogging_periods": cogging_counts}


def nut_travel(run: RigRun, params: ParameterSet) -> np.ndarray:
    """The nut position per sample [m]: the LVDT's, or (no LVDT) the travel integrated from the measured motor
    speed through the screw's kinematics."""
    x = np.asarray(run.signals["nut_position"], float) if run.has("nut_position") else np.array([np.nan])
    if np.isfinite(x).any():
        return x
    r_kin = params.value("screw.lead") / (2 * math.pi * params.value("gear.ratio"))
    return speed_integral(run.time, np.nan_to_num(measured_motor_speed(run))) * r_kin


def _screw_revolutions(params: ParameterSet, runs) -> str | None:
    """A ripple once per screw revolution is told from a drag that depends on the nut position (a bump, a worn
    spot, a trend of the base's own drags along the stroke) only where the same screw angle recurs at another
    nut position: the nut's travel in one run must span two leads.  Reason to skip, or None."""
    lead = params.value("screw.lead")
    span = 0.0
    for r in runs:
        x = nut_travel(r, params)
        span = max(span, float(np.nanmax(x) - np.nanmin(x)))
    if span >= 2 * lead:
        return None
    return (f"the nut travels {span * 1e3:.3g} mm, less than two screw leads ({2 * lead * 1e3:.3g} mm): a ripple "
            "once per revolution cannot be told from a position-dependent drag")


#: Candidates a record cannot resolve (name -> function(params, runs) -> reason to skip, or None).
RESOLVES: dict[str, Callable] = {"screw_friction_ripple": _screw_revolutions}


def _ripple_period(params: ParameterSet) -> float:
    return params.value("screw.lead")  # once per screw revolution: one lead of nut travel


def _cogging_period(params: ParameterSet) -> float:
    # n periods per motor revolution, ratio motor revolutions per lead
    return params.value("screw.lead") / (params.value("gear.ratio") * params.value("drive.cogging_periods"))


#: Angle-periodic candidates: name -> function(fitted params) -> the period of its angle in nut travel [m].  Their
#: held-out gain must repeat over the travel (:mod:`thsa_control.trace.periodicity`).
PERIODS: dict[str, Callable] = {"screw_friction_ripple": _ripple_period, "cogging_torque": _cogging_period}

#: The residual signature's variable an angle-periodic candidate's torque is periodic in
#: (:func:`~thsa_control.trace.signature.signature_tests`: the harmonics of that angle).
ANGLE_OF: dict[str, str] = {"screw_friction_ripple": "screw_angle", "cogging_torque": "motor_angle"}

#: The harmonic of :data:`ANGLE_OF`'s angle an added periodic effect's torque has (name -> function(fitted params)):
#: the signature tests that angle beyond it (``signature_tests``' ``added``).
ANGLE_HARMONIC: dict[str, Callable] = {"screw_friction_ripple": lambda params: 1,
                                       "cogging_torque": lambda params: int(round(params.value("drive.cogging_periods")))}

def _start_drivetrain(params: ParameterSet, runs) -> ReadStart:
    from ..fit.resonance_screen import drivetrain_resonance_start

    found: dict = {}
    values = drivetrain_resonance_start(params, runs, found=found)
    return ReadStart(values, (f"the torsional mode the record rings at, {found['frequency_hz']:.1f} Hz (twist rate "
                              f"over motor speed: gain {found['gain']:.1f}, coherence {found['coherence']:.2f}, "
                              f"run {found['run']})") if values else "")


#: Starting values read off the runs (:attr:`CandidateSpec.start` -> function(params, runs) -> {name: value}).
STARTS: dict[str, Callable] = {"loadpath_static": _start_loadpath, "drivetrain_resonance": _start_drivetrain}


# ----------------------------------------------------------------------------- candidates
def _generic_spec(name: str, params: ParameterSet) -> CandidateSpec | None:
    """An effect without a table entry: its non-zero, finitely bounded parameters (at most 3) are free."""
    free = [n for n in EFFECTS[name].parameters
            if n in params and params[n].value != 0 and math.isfinite(params[n].max - params[n].min)][:3]
    return CandidateSpec(name, tuple(free), {}, "all") if free else None


def candidate_specs(model_effects: Iterable[str], params: ParameterSet, names: Sequence[str] | None = None
                    ) -> list[CandidateSpec]:
    """Candidates for a model: every library effect it does not declare (or ``names``)."""
    have = set(model_effects)
    excluded = not_candidates()
    pool = names if names is not None else [e for e in EFFECTS if e not in excluded]
    out = []
    for n in pool:
        if n in have:
            continue
        spec = CANDIDATES.get(n) or _generic_spec(n, params)
        if spec is not None and all(p in params for p in (*spec.free, *spec.profile)):
            out.append(spec)
    return out


#: Fewest samples (over all runs) a candidate's window must hold for the candidate to be scored on them; the same
#: count of moving samples outside a window is what determines the declared parameters read at its reference
#: condition (:func:`reference_not_determined`)
MIN_WINDOW_SAMPLES = 50


def reference_not_determined(runs: Sequence[RigRun], params: ParameterSet, names: Iterable[str]) -> dict[str, str]:
    """Declared parameters (of ``names``) the runs do not determine because they are defined at a reference
    condition the runs never reach while moving (:attr:`CandidateSpec.reference`): name -> reason.

    ``gear.viscous_friction`` is the 25 degC drag (its source in the parameter file; ``temperature_friction``
    reads it as ``b_25`` and scales it by ``exp(a_v (T_ref - T))``).  A run that moves only far from 25 degC
    measures the drag at its own temperature: fitted there, the 25 degC coefficient takes what the temperature
    effect would explain (measured on rig-sim's cold ramp at -30 degC: 7.4e-4 N m s/rad against the file's 8e-5,
    which left the temperature candidate 17 % of its window).  Without a temperature law the data say nothing of
    the drag at 25 degC: the parameter is held at its file value, as a candidate's undetermined parameter is.
    """
    names = list(names)
    out: dict[str, str] = {}
    for spec in CANDIDATES.values():
        ref = [n for n in spec.reference if n in names and n not in out]
        if not ref:
            continue
        n_ref = sum(int(np.sum(_window("moving", r, params) & ~_window(spec.window, r, params))) for r in runs)
        if n_ref < MIN_WINDOW_SAMPLES:
            for n in ref:
                out[n] = (f"defined at the reference condition of {spec.name} (outside its '{spec.window}' window: "
                          f"{_window_text(spec.window, params)}); the runs move there on {n_ref} samples "
                          f"(fewer than {MIN_WINDOW_SAMPLES}), so they measure it only together with {spec.name}")
    return out


#: The ``cold`` window: farther than ``COLD_BAND_K`` from the temperature of the declared (level-A) friction,
#: ``friction.reference_temperature`` (``COLD_REFERENCE_C`` where a parameter set lacks it: the embedded actuator's)
COLD_REFERENCE_C, COLD_BAND_K = 25.0, 5.0


def _cold_reference(params: ParameterSet | None) -> float:
    """The temperature the declared friction is defined at [degC] (the ``cold`` window is away from it)."""
    if params is not None and "friction.reference_temperature" in params:
        return params.value("friction.reference_temperature")
    return COLD_REFERENCE_C


def _window_text(kind: str, params: ParameterSet | None) -> str:
    """What a window's reference condition (its complement) is, for the reasons given to the user."""
    if kind == "cold":
        return f"within {COLD_BAND_K:g} K of {_cold_reference(params):g} degC"
    return kind


#: The windows a candidate may act in (:attr:`CandidateSpec.window`, :func:`_window`).
WINDOWS = ("moving", "all", "loaded", "reversal", "clearance", "cold", "resolved_cogging", "load_change")

#: (``MOTION_SIGMA``: a speed beyond this many noise standard deviations, on two successive samples of one sign, is
#: motion, the clearance window's test; defined in :mod:`~thsa_control.trace.signature`, whose redundant-sensor test
#: uses it too)


def _largest_clearance() -> float:
    """The largest pawl pitch the backlash candidate searches [rad of screw rotation]: the end of its profile
    range (the papers' 8.57 deg maximum, searched up to twice that)."""
    spec = EFFECTS["noback_backlash"].candidate
    return float(spec.profile["noback.pawl_pitch"][1])


def clearance_window(run: RigRun, travel: float) -> np.ndarray:
    """Samples where the screw moves within ``travel`` [rad] of its last change of direction.

    A circumferential clearance (the no-back's pawl play) is crossed only there: after the screw changes
    direction (a reversal, a back-drive by the load once the drive is off, or the record's first motion, the
    clearance left where the ratchets stopped being unknown), the pawl that now locks is met within one pitch
    and then holds.  Elsewhere a clearance model predicts what a model without it does, so a window of a fixed
    time around reversals and stops measures other things: on rig-sim's trim stops the 0.3 s after the arrest
    held the drive train's ringing (a 48 Hz mode of the rotors on the rig base's gear stiffness, which the
    screw-speed sensor does not see and no rigid model predicts) and the deceleration with the motor on, and
    the back-drive at the load's application (a start from rest) was outside it.  The screw's motion is read
    from its speed sensor where there is one (the rotors ring while the screw is held), else from the motor
    speed over the gear ratio; still samples are not in the window, and a stop does not end a direction (the
    clearance is not opened again by a restart in the same direction).
    """
    t = np.asarray(run.time, float)
    if t.size < 2:
        return np.zeros(t.shape, bool)
    ws = np.asarray(run.signals["screw_speed"], float) if "screw_speed" in run.source_columns else None
    if ws is None or not np.isfinite(ws).any():
        ws = np.asarray(measured_motor_speed(run), float) / run.gear_ratio
    ws = np.nan_to_num(ws)
    sign = motion_sign(ws, motion_band(ws))
    moving = sustained_motion(sign)
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    out = np.zeros(t.size, bool)
    last, turned = 0, 0.0
    for k in range(1, t.size):
        if not moving[k]:
            continue
        if sign[k] != last:
            last, turned = int(sign[k]), 0.0
        turned += abs(ws[k]) * dt[k]
        out[k] = turned <= travel
    return out


def _window(kind: str, run: RigRun, params: ParameterSet | None = None) -> np.ndarray:
    s = run.signals
    w = np.nan_to_num(measured_motor_speed(run))
    moving = np.abs(w) > stop_band(w)
    load = np.asarray(s["load_force"], float)
    if kind == "all":
        return np.ones(w.shape, bool)
    if kind == "moving":
        return moving
    if kind == "loaded":
        return moving & (np.abs(load) > max(0.05 * float(np.max(np.abs(load))), 500.0))
    if kind == "reversal":
        return moving & (reversal_proximity(run.time, w, deadband=0.05 * float(np.max(np.abs(w)))) < 0.3)
    if kind == "clearance":  # the first pitch of screw travel after each change of direction
        return clearance_window(run, _largest_clearance())
    if kind == "resolved_cogging":  # the motor turns slowly enough that the cogging's period spans 4 samples or
        # more, at the count of ``params`` (the engine evaluates it at a fit's count; the base's transients are left
        # out by the scoring mask)
        n = params.value("drive.cogging_periods") if params is not None and "drive.cogging_periods" in params else 6.0
        return cogging_resolved(run, n, steady=False)
    if kind == "load_change":  # within 0.3 s of a load change of 5 % of the run's range (500 N at least): where
        # a compliant load path shows in the LVDT (the segments start at the static deflection of the load)
        t = np.asarray(run.time, float)
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        k = max(int(round(0.3 / dt)), 1)
        out = np.zeros(t.size, bool)
        if t.size > k:
            d = np.abs(load[k:] - load[:-k]) > max(0.05 * float(np.ptp(load)), 500.0)
            idx = np.flatnonzero(d)
            for i in idx:  # the change spans samples i .. i + k
                out[i:i + k + 1] = True
        return out
    if kind == "cold":
        temp = np.asarray(s["temperature"], float)
        return np.abs(temp - _cold_reference(params)) > COLD_BAND_K
    raise ValueError(f"unknown window {kind!r}")

