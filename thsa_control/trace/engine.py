"""Trace a residual to the effect the model lacks: candidates, forward selection, honest scoring.

:func:`trace` takes rig runs and a declared model (a level plus effects) and

1. fits the model's documented default uncertain parameters
   (:data:`DEFAULT_UNCERTAIN`, regularised by priors at the parameter file's
   values) by multiple shooting driven by the measured current
   (:class:`~thsa_control.fit.identify.Identifier`), with every
   ``holdout_every``-th segment held out of the parameter fit;
2. for every library effect the model does not declare (:data:`CANDIDATES`,
   plus any other registered effect, with its own parameters free), adds it,
   re-identifies the declared and the candidate's parameters, and scores it:

   * ``holdout_chi2_drop``: drop of the noise-weighted squared error on the
     held-out segments (data the parameter fit did not see);
   * ``window_reduction``: RMS drop of the held-out error inside the window
     where the effect acts (moving, loaded, near a reversal, cold ...);
   * plausibility: no identified parameter at a bound, none collapsing to
     zero (``|value| < 2 stderr``);
   * calibration: the same candidate fitted to a *null run* (the current
     model's own segment predictions driven by the same measured current,
     with white noise of the measured level) gives the drop noise alone buys;

   a candidate is significant when its held-out drop exceeds both the
   ``chi2(k)`` quantile at ``alpha`` and ``null_factor`` times its null drop,
   its window error falls by ``min_window_reduction``, the window error of its
   own channel (``CandidateSpec.channel``, where measured) does not grow by
   more than ``max_channel_increase``, nor that channel's error over the
   whole record, it is plausible, and (an angle-periodic one: screw ripple,
   cogging) its gain repeats over the nut travel (``periodic_repeat``);
3. keeps the most significant candidate, makes it part of the model and
   repeats (forward selection) until none is significant; when other
   plausible candidates explain the same part of the residual (held-out drops
   closer than noise can separate, see :func:`_rivals`) it names none of them,
   lists them under ``ambiguous`` and stops;
4. describes the remaining residual (:mod:`thsa_control.trace.signature`)
   and says ``unexplained`` when it is still structured.

This module owns the settings, the result and the forward-selection driver; the candidates, their windows
and plausible magnitudes are :mod:`thsa_control.trace.candidates`'s, the fits and their scoring (with the
base correction and the null runs) :mod:`thsa_control.trace.scoring`'s, and the description of what a fit
leaves :mod:`thsa_control.trace.residual`'s.
Nothing here draws or writes files (:mod:`thsa_control.report.trace` does).
Candidate fits run in parallel processes (``workers``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..data.rigdata import RigRun, measured_motor_speed
from ..errors import ThsaError
from ..fit.identify import IdentificationSettings, estimate_noise
from ..fit.replay import rig_declared_effects
from ..fit.shooting import HOLDOUT_LAYOUTS
from ..data.rigformat import speed_sensor_intervals
from ..fit.replay import check_run_model
from ..model import EFFECTS, CandidateSpec, build_plant, resolve_effects
from ..model.laws import torque_constant
from ..model.params import ParameterSet, default_parameters
from .candidates import (CANDIDATES, DEFAULT_UNCERTAIN, EFFICIENCY_EXPLAINER, INERTIA_EXPLAINER, MIN_WINDOW_SAMPLES,
                         ANGLE_OF, HOLDING_COEFFICIENTS, PERIODS, PLAUSIBLE, SECOND_STAGE_GATES,
                         PROFILE_GRIDS, RESOLVES, STARTS, WINDOWS, reference_not_determined,
                         _window, turning_band,
                         candidate_specs, not_candidates, nut_travel)
from . import backward as bw
from .holding import drive_off_holds, holding_finding, holding_margin
from . import periodicity
from . import weights as wt
from .residual import _regime_errors, _segment_rate_not_tested, _signature
from .scoring import (_amplitude_out, _at_edge, _base_correction, _channel_errors, _chi2_by_channel,
                      _explainers_at_bound, _held_out,
                      _holdout_segment_changes,
                      _held_params, _null_runs, _param_entry, _plausibility, no_back_fault, reason_kind,
                      _run_jobs,
                      _signature_brief, admission_tests, beats_null, holdout_total, null_drop, scaled_threshold,
                      zero_is_absent, ROBUST_TESTS)
from .lift import (beyond_base, better, contribution, current_proportional_is_base, interior, joint_verdict,
                   lift_names, lifted as lifted_bounds, not_ruled_out)
from .separability import current_offset_torque
from .signature import SignatureSettings, base_transients, split_remainder
from .threads import limit_blas_threads

__all__ = ["TraceSettings", "CandidateSpec", "CANDIDATES", "DEFAULT_UNCERTAIN", "TraceResult", "trace",
           "candidate_specs", "TRACE_FORMAT", "not_candidates", "PLAUSIBLE", "EFFICIENCY_EXPLAINER", "WINDOWS", "score_masks"]

TRACE_FORMAT = "thsa-trace/1"

#: candidate windows at the transients themselves: scored on every sample (``score_outside_transients``)
TRANSIENT_WINDOWS = ("reversal", "clearance", "load_change")
#: candidate windows of a periodic torque's resolved harmonic: scored outside the base's transients judged on the speed
#: averaged over the transient time (``base_transients(sustained=True)``): rig-sim's cogging (0.05 N m, 18 per
#: revolution) swings the speed of its slow record so fast that the plain rule called 97 % of it a transient (26 of
#: its 904 moving samples were scored)
SUSTAINED_WINDOWS = ("resolved_cogging",)
#: candidate windows that depend on the candidate's fitted parameters (the cogging's resolved samples on its count):
#: evaluated at each fit's values
FITTED_WINDOWS = ("resolved_cogging",)


@dataclass(frozen=True)
class TraceSettings:
    """How :func:`trace` fits, scores and selects.

    Parameters
    ----------
    segment_duration, substeps : float, int
        Multiple shooting (as :class:`IdentificationSettings`).
    holdout_every : int
        One segment in each block of k is held out of the parameter fits and scored.
    holdout_layout : {"every_kth", "dithered"}
        Its place in the block (:func:`~thsa_control.fit.shooting.held_out_segments`): the last (default), or drawn
        from a fixed seed, for a record whose test profile repeats every multiple of k segments (every k-th then
        hides the same phase of each repeat from the fits; the every-segment check reports what that changed).
    max_nfev : int
        Evaluation limit of each fit.
    fit_time_budget : float or None
        Wall-time limit of each fit [s] (best point kept, flagged).
    prior_relative_sd : float
        Priors of the declared uncertain parameters at the parameter file's values.
    uncertain : tuple of str or None
        Declared parameters to fit (None: :data:`DEFAULT_UNCERTAIN` of the level).
    candidates : tuple of str or None
        Candidate effects (None: every library effect not in the model).
    alpha : float
        Level of the ``chi2(k)`` test of the held-out drop.
    null_factor : float
        The held-out drop must exceed this many times the drop on the null run.
    min_window_reduction : float
        Required relative drop of the held-out RMS inside the candidate's window.
    max_channel_increase : float
        A candidate that makes the held-out RMS of its own channel (where it
        shows, :attr:`CandidateSpec.channel`) inside its window grow by more
        than this fraction is refused, whatever it buys on the others (a
        lagging motor-speed sensor fitted as a compliant drive train made the
        screw-speed error five times larger).  The same bar holds for its
        channel's RMS over the whole record (all samples, the base's
        transients included): a window scored outside the transients does
        not see where a compliance or a clearance acts most, at starts and
        stops (measured on a cold rig-sim null: a drive-train compliance
        with a 7 % window drop made the screw-speed error 30 % larger, a
        no-back backlash with a 13 % window drop the motor-speed error 29 %).  Other channels may trade: a
        cogging fit aligns its angle through the segments' nut positions and
        doubles the LVDT's small error.
    max_effects : int
        Forward selection stops after this many found effects (the base step's detailed declared component,
        what the base contains, is not counted: counted, it left two found effects on every record whose no-back
        the base step detailed).
    periodic_repeat : bool
        An angle-periodic candidate (:data:`~thsa_control.trace.candidates.PERIODS`: the screw ripple once per
        lead of nut travel, the cogging once per ``lead / (ratio x count)``) whose period is two bins of the
        nut-position test or longer (:func:`_repetition`; the cogging's is far shorter) is significant only when its
        held-out drop outside the one period of travel that carries most of it still passes the ``chi2(k)``
        quantile at ``alpha``, scaled as the ambiguity gap (reduced held-out chi2 x IACT)
        (:mod:`~thsa_control.trace.periodicity`; ``periodicity`` and ``not_periodic`` in ``trace.json``).  A
        ripple is the same in every revolution; within one revolution it is any drag that depends on the nut
        position.  Measured on rig-sim's friction bump (8 N m at the screw at 5 mm): the ripple fitted to it
        gained 4613 in the lead that holds the bump and lost 1884 over the three other leads of travel.  A
        shorter period (the cogging) cannot leave one out: its held-out drop must pass the same scaled threshold
        in each half of the travel (:func:`~thsa_control.trace.periodicity.halves_test`).
    workers : int
        Parallel processes for candidate fits (1: in this process).
    seed : int
        Noise of the null runs.
    signature : SignatureSettings
    base_corrections : bool or None
        Fit the base-correction step first (the constant-torque explainers,
        the screw efficiencies and the motor-side inertia within their plausible magnitudes,
        :data:`PLAUSIBLE`), reported as base corrections, not as found
        effects.  None: on when the candidates are the default pool (a named
        candidate list is scored as effects only, as before).
    determination_z : float
        One test decides both identifiability and "collapses to zero"
        (:func:`~thsa_control.trace.scoring.determination`): with the
        standard error the runs give (with the base corrections' priors, plausible
        magnitudes with a source, but without the regularising priors around the
        declared parameters' current values: :attr:`ParameterEstimate.stderr_data`), a
        candidate's parameter whose estimate is within ``z`` standard errors
        of zero *and* of its reference magnitude (file value, seed or
        plausible bound) is not determined by the run: held at its file
        value, the candidate refitted and judged on what the others explain.
        Within ``z`` of zero but not of its reference magnitude, it collapses
        to zero (implausible).  2: the two-sided 95 % normal quantile (1.96).
        Both tests only where zero is the effect's neutral value; a stiffness,
        a damping or a signed free play is not determined when its standard
        error exceeds its reference magnitude, and never "collapses".
    window_tolerance : float
        A significant physical effect whose window RMS drop is within this of
        the best constant-torque explainer's comes before it
        (:func:`_physical_first`).
    score_outside_transients : bool
        With the base step (data the declared model may not describe), score
        the candidates' held-out drops, window drops and null drops on the
        samples outside the base's transients
        (:func:`~thsa_control.trace.signature.base_transients`: starts, stops,
        reversals, load changes), except candidates that act there (windows
        ``reversal``, ``clearance``): a declared model of another
        rig's base leaves its largest residual at those transients, and a
        few such held-out segments decided the sign of every drop.
    robust_constant_torque : bool
        With the base step, a constant-torque explainer (a Coulomb or direction drag, an axial force; within or
        beyond its base correction) is significant only when it improves a majority of the held-out segments
        of its window (outside the base's transients) beyond chance: the one-sided ``robust_test`` of the per-segment
        chi2 drops at ``alpha``.  A constant torque acts on every moving sample
        alike, so a real one lowers the error of most segments; the pooled held-out drop of a declared model of
        another rig's base is carried by a few segments (measured: an axial force beyond its bound, the first
        effect named on rig_direction_friction, improved 6 of the 15 held-out segments of its window outside the
        transients; over all 33 held-out segments 13, three of them carrying 91 % of the change).  The held-out segments are separate shooting
        segments, each started from its own fitted state, and 2 segment lengths apart: their drops are taken
        as independent.
    robust_test : str
        The test of ``robust_constant_torque``: ``"signed-rank"`` (default; Wilcoxon's one-sided signed-rank test
        of the per-segment drops, ``window_segments.signed_rank_p``) or ``"sign"`` (the sign test,
        ``window_segments.sign_p``).  The sign test counts a segment the candidate hardly changes as a full vote;
        on a record whose base differs, the segments where a constant torque matters little (slow motion, light
        load) are coin flips of small size and dilute the segments where it acts.  The signed-rank test weighs each
        segment by the rank of its change, so those count little, while a drop carried by a few segments (large
        ranks on few segments, the rest against it) still fails.
    joint_lift : bool
        With the base step, where a Coulomb-drag or axial-force correction ran to its plausible bound: the
        explainers lifted together (:func:`~thsa_control.trace.lift.joint_verdict`) and the lifted fits started
        from the unsaturated interior too (:func:`~thsa_control.trace.lift.interior`).  From the saturated fit a
        lifted explainer is fitted with the others pinned where the bounded fit left them (measured: an axial
        force lifted on a record that determines it reached 1080 N of the planted 1500 with both efficiencies
        left at their bounds).
    rig_hardware : bool
        Complete the declared model with what the runs' own rig description
        declares (:func:`~thsa_control.fit.replay.rig_declared_effects`: a
        JSON ``rig.motors = 2`` is a second rotor carried along, the
        ``standby_motor`` effect), reported under ``declared_from_runs``.
        It is hardware, not a finding: without it the model has half the
        rotor inertia (rig-sim's speed-chirp run: motor-speed error 11.5 rad/s
        rms instead of 1.7).
    """

    segment_duration: float = 0.05
    substeps: int = 1
    holdout_every: int = 3
    holdout_layout: str = "every_kth"
    max_nfev: int = 40
    fit_time_budget: float | None = 120.0
    prior_relative_sd: float = 0.1
    tolerance: float = 1e-7
    uncertain: tuple[str, ...] | None = None
    candidates: tuple[str, ...] | None = None
    alpha: float = 1e-3
    null_factor: float = 3.0
    min_window_reduction: float = 0.05
    max_channel_increase: float = 0.1
    max_effects: int = 3
    #: an angle-periodic candidate (screw ripple, cogging) must gain outside the one period of nut travel that
    #: carries most of its held-out drop (:mod:`thsa_control.trace.periodicity`): a ripple is the same in every
    #: revolution, a friction bump at one place is not
    periodic_repeat: bool = True
    #: a candidate that made the held-out error worse is skipped in the next round (it rarely helps once another
    #: effect is in); when that round finds nothing significant, or no other candidate is left to score, the skipped
    #: ones are fitted on the final model before the search stops (a retry round, ``retry`` in ``trace.json``; a round
    #: of their own when nothing else was left): no stop with a candidate untried
    retry_hurt: bool = True
    workers: int = 2
    seed: int = 0
    signature: SignatureSettings = field(default_factory=SignatureSettings)
    base_corrections: bool | None = None
    determination_z: float = 2.0
    window_tolerance: float = 0.01
    #: how the speed sensors read, over each run's declaration (IdentificationSettings.speed_sensors): channel
    #: -> difference interval [s], "sample" or "instantaneous"; None: each run's own (its JSON's
    #: ``speed_sensors``, else its ``sensors`` text as a reported fallback, else instantaneous)
    speed_sensors: Mapping[str, object] | None = None
    score_outside_transients: bool = True
    robust_constant_torque: bool = True
    robust_test: str = "signed-rank"
    rig_hardware: bool = True
    #: with the base step, when a constant-torque base correction sits at its plausible bound: fit the whole
    #: plausible set lifted together against all bounded (one held-out likelihood ratio, reported per round as
    #: ``joint_lift`` with the single candidate that carries it), and fit each constant-torque candidate from the
    #: unsaturated interior as well as from the bounded optimum, keeping the start the training samples prefer
    #: (:mod:`~thsa_control.trace.lift`)
    joint_lift: bool = True
    #: segments start the plant's fast internal modes quasi-static (IdentificationSettings.quasi_static_starts);
    #: None: with the base step (data the declared model may not describe), free otherwise
    quasi_static_starts: bool | None = None
    #: what the channels are weighted by in the fits and the chi2 scores: "sensor_noise" (each channel's sensor
    #: noise) or "base_residual" (the larger of the sensor noise and the declared model's residual RMS on that
    #: channel: the maximum-likelihood scale of a channel whose error the base leaves is that error, not the
    #: sensor noise; with sensor-noise weights a channel carrying several times its noise of base error outweighs
    #: the others and a candidate's parameters absorb that error, docs/trace_notes.md, rig_drivetrain_compliance).
    #: The residual-to-noise flags of the signature keep the sensor noise.
    channel_weights: str = "sensor_noise"
    #: after each round that adds an effect, judge every earlier found effect again given the later ones and remove
    #: one that no longer earns its place (:mod:`thsa_control.trace.backward`); report the kept ones in the order of
    #: their leave-one-out held-out drops
    backward: bool = True
    #: after the search, fit each found effect's parameters again with every channel scaled by the larger of its
    #: sensor noise and the final model's residual RMS on it, and report where the estimate depends on the
    #: weighting (both values and the range they span; :mod:`thsa_control.trace.weights`).  The decisions keep
    #: the sensor-noise weights.  Only with ``channel_weights = "sensor_noise"``
    weight_check: bool = True
    #: fit the final model once more on every segment, the held-out ones too, from its values, and report each found
    #: effect's parameter that moves beyond 2 combined standard errors and 10 % (``every_segment`` in its entry,
    #: with the range the two fits' 95 % intervals span; the base corrections' and declared parameters' moves in the
    #: doc's ``every_segment.moved_other``): the held-out segments' places decided it (a test profile that repeats
    #: every multiple of ``holdout_every`` segments hides one phase of it from the search's fits).  Reported, not
    #: used to select
    every_segment_check: bool = True
    #: an angle test's harmonics in step with the fit segments (``segment_rate_harmonics``: at a constant speed the
    #: tested samples are a comb at the segment rate) tested once more on the final model fitted (segment states
    #: only) on a second grid of another segment length where they are not in step (``segment_rate_check`` in the
    #: test; :func:`_segment_rate_check`)
    segment_rate_check: bool = True
    #: the final model's values (``final_parameters``, each found effect's ``parameters_final``, ``error_after``)
    #: are the every-segment fit's where it converged and fits every segment at least as well as the search's last
    #: fit: the held-out segments decide which effects the model has, then every sample estimates their values
    #: (``every_segment["adopted"]``).  The signature and the ``unexplained`` verdict stay on the search's last fit
    #: (its held-out residual).  False: the search's values (the training segments only)
    final_on_every_segment: bool = True
    #: after each round that adds an effect, an earlier effect's parameter that its own fit held because its estimate
    #: was undecided (a standard error from the run, within 2 of both zero and its reference: not a null direction)
    #: is freed once more on the new model and kept free where that fit determines it (``held_refreed`` in the
    #: round, ``determined_later`` in the effect's entry): what confused it may be what was just added (measured:
    #: a pawl clearance the base step's model lacks sent the no-back's retraction disk coefficient to 0.056 +- 0.19
    #: N m/N; held at the file's 0.0043 where the rig has 0.00455, its 7.5 N m of loaded-disk drag at 30 kN was
    #: later named an axial force of 2 kN beyond the base; :func:`_refree_held`)
    refree_held: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        if self.channel_weights not in ("sensor_noise", "base_residual"):
            raise ValueError(f"TraceSettings.channel_weights = {self.channel_weights!r}: expected 'sensor_noise' or "
                             "'base_residual'")
        if self.robust_test not in ROBUST_TESTS:
            raise ValueError(f"TraceSettings.robust_test = {self.robust_test!r}: expected one of "
                             f"{', '.join(map(repr, ROBUST_TESTS))}")
        if self.speed_sensors is not None:
            from ..data.rigformat import SPEED_SENSOR_COLUMNS, speed_interval_from

            for k, v in dict(self.speed_sensors).items():
                if k not in SPEED_SENSOR_COLUMNS and k not in SPEED_SENSOR_COLUMNS.values():
                    raise ValueError(f"TraceSettings.speed_sensors: unknown channel {k!r}; channels are "
                                     f"{', '.join(SPEED_SENSOR_COLUMNS.values())}")
                speed_interval_from(v, f"TraceSettings.speed_sensors[{k!r}]")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"TraceSettings.substeps = {self.substeps!r} must be an integer >= 1")
        if not (isinstance(self.holdout_every, int) and self.holdout_every >= 2):
            raise ValueError(f"TraceSettings.holdout_every = {self.holdout_every!r} must be an integer >= 2")
        if self.holdout_layout not in HOLDOUT_LAYOUTS:
            raise ValueError(f"TraceSettings.holdout_layout = {self.holdout_layout!r} must be one of "
                             + ", ".join(HOLDOUT_LAYOUTS))
        if not (isinstance(self.workers, int) and self.workers >= 1):
            raise ValueError(f"TraceSettings.workers = {self.workers!r} must be an integer >= 1")
        if not (0 < self.alpha < 1):
            raise ValueError(f"TraceSettings.alpha = {self.alpha!r} must lie in (0, 1)")
        if not (isinstance(self.max_effects, int) and self.max_effects >= 0):
            raise ValueError(f"TraceSettings.max_effects = {self.max_effects!r} must be an integer >= 0")
        if self.candidates is not None:
            bad = [c for c in self.candidates if c not in EFFECTS]
            if bad:
                raise ValueError(f"TraceSettings.candidates: unknown effect(s) {bad}; effects are {', '.join(EFFECTS)}")


@dataclass(frozen=True)
class TraceResult:
    """What the tracer found (:meth:`to_dict` is ``trace.json``, schema ``docs/trace_schema.json``)."""

    doc: dict
    fits: dict  # label -> fit summary with time series (for the report)

    def to_dict(self) -> dict:
        return self.doc

    @property
    def effects_added(self) -> list[str]:
        return [e["name"] for e in self.doc["effects_added"]]

    @property
    def unexplained(self) -> bool:
        return bool(self.doc["unexplained"])


def score_masks(runs: Sequence[RigRun], transient_time: float) -> dict[str, dict[str, np.ndarray]]:
    """Window -> run name -> the samples a candidate of that window is scored on (True) when the base step runs:
    outside the base's transients (:func:`~thsa_control.trace.signature.base_transients`), except the windows at the
    transients themselves (:data:`TRANSIENT_WINDOWS`: absent, scored on every sample of the window).

    A periodic torque ripples the speed itself: where a candidate's window is its resolved harmonic
    (:data:`SUSTAINED_WINDOWS`, the cogging) the base's transients are judged on the speed averaged over the
    transient time (its own ripple is none), and its starts and stops are also where the speed crosses the band its
    window calls motion (the motor turning beyond its sensor noise, :func:`~thsa_control.trace.candidates.turning_band`),
    not only 5 % of the top speed: the end of a position loop's creep (2 % of the top speed) is a stop, where the
    base's stiction acts
    (rig_cogging_steps: the same seed without the cogging left 2.85 x the noise variance in the window with the
    creep's stops in it, 1.31 x without them; ``bench/window_ceiling.py``)."""
    steady = {r.name: ~base_transients(r.time, measured_motor_speed(r), r.signals["load_force"], transient_time,
                                       load_steps=True) for r in runs}
    sustained = {r.name: ~base_transients(r.time, measured_motor_speed(r), r.signals["load_force"], transient_time,
                                          sustained=True, motion_band=turning_band(r)) for r in runs}
    return {w: (sustained if w in SUSTAINED_WINDOWS else steady) for w in WINDOWS if w not in TRANSIENT_WINDOWS}


# ----------------------------------------------------------------------------- the tracer
def trace(runs: RigRun | Sequence[RigRun], level: str | None = "A", effects: Iterable[str] = (), *,
          remove: Iterable[str] = (), params: ParameterSet | None = None, settings: TraceSettings | None = None,
          progress: Callable[[str], None] | None = None) -> TraceResult:
    """Fit the declared model, then add library effects by forward selection while one is significant.

    Parameters
    ----------
    runs : RigRun or sequence of RigRun
        Need ``motor_current`` and a speed or position channel.  Their
        controller is not used (the replay is driven by the measured current),
        so any rig the parameter file describes can be traced.
    level, effects, remove : declared model (a plain screw drive: ``"A"``
        with ``remove=["noback_ideal"]``, or ``None`` with its effects)
    params : ParameterSet, optional
        Initial values, bounds and priors (default: the embedded actuator).
    settings : TraceSettings, optional
    progress : callable, optional
        ``progress(message)`` for each step and fit.

    Returns
    -------
    TraceResult
    """
    t_start = time.perf_counter()
    st = settings or TraceSettings()
    st.validate()
    limit_blas_threads(1)
    runs = [runs] if isinstance(runs, RigRun) else list(runs)
    if not runs:
        raise ThsaError("trace: no run given")
    names = [r.name for r in runs]
    if len(set(names)) != len(names):
        raise ThsaError(f"trace: runs must have distinct names, got {names}")
    params = params or default_parameters()
    say = progress or (lambda msg: None)
    declared = resolve_effects(level, add=effects, remove=remove)
    # the hardware the runs describe (a second rotor carried along) is part of the declared model, not a finding
    from_runs = {e: why for e, why in rig_declared_effects(runs).items()
                 if e not in declared and e not in remove} if st.rig_hardware else {}
    if from_runs:
        declared = resolve_effects(level, add=[*effects, *from_runs], remove=remove)
        say("declared model completed from the runs' rig description: "
            + "; ".join(f"{e} ({why})" for e, why in from_runs.items()))
    lvl = (level or "A").upper()
    uncertain = tuple(st.uncertain) if st.uncertain is not None else DEFAULT_UNCERTAIN.get(lvl, DEFAULT_UNCERTAIN["A"])
    base_plant = build_plant(None, declared, params=params)

    def plant_of(effects, p):
        """The plant of an effect set (the declared one is built once)."""
        return base_plant if tuple(effects) == tuple(declared) else build_plant(None, effects, params=p)

    uncertain = tuple(n for n in uncertain if n in base_plant.parameters)
    # identifiability of the declared set itself: a parameter defined at a reference condition the runs never
    # reach while moving (the 25 degC drag on a cold-only record) is held at its file value, reported; a parameter
    # the user names (``uncertain``) is fitted as asked
    ref_held = reference_not_determined(runs, params, uncertain) if st.uncertain is None else {}
    declared_held = [{"parameter": n, "held_at": params.value(n), "unit": params[n].unit, "reason": why}
                     for n, why in ref_held.items()]
    if ref_held:
        uncertain = tuple(n for n in uncertain if n not in ref_held)
        say("not determined by these runs: " + "; ".join(f"{h['parameter']} held at {h['held_at']:g} {h['unit']} "
                                                         f"({h['reason']})" for h in declared_held))
    # the replay is current-driven: the rig's controller plays no part (and need not be one we model)
    fit_runs = [dataclasses.replace(r, controller=None) for r in runs]
    channels = tuple(c for c in ("motor_speed", "nut_position", "screw_speed")
                     if any(c in r.source_columns for r in runs))
    noise = {c: float(np.mean([estimate_noise(r.signals[c]) for r in runs if c in r.source_columns]))
             for c in channels}
    sensor_noise = dict(noise)  # the sensors' own; ``noise`` becomes the channel weights (channel_weights)

    # fast internal modes (the surface on a compliant load path) start each segment quasi-static on data the
    # declared model may not describe (with the base step): free, they rang to absorb the motor-speed mismatch
    quasi_static = (st.quasi_static_starts if st.quasi_static_starts is not None else
                    st.base_corrections if st.base_corrections is not None else st.candidates is None)

    def id_settings(prior: bool = True, no_prior=(), priors=None) -> IdentificationSettings:
        return IdentificationSettings(no_prior=tuple(no_prior), segment_duration=st.segment_duration, substeps=st.substeps, channels=channels,
                                      noise=noise, max_nfev=st.max_nfev, tolerance=st.tolerance, time_budget=st.fit_time_budget,
                                      prior_relative_sd=st.prior_relative_sd if prior else None,
                                      holdout_every=st.holdout_every, holdout_layout=st.holdout_layout,
                                      priors=dict(priors or {}) or None,
                                      quasi_static_starts=quasi_static, speed_sensors=st.speed_sensors)

    plaus = {k: fn(params, runs) for k, fn in PLAUSIBLE.items()}

    def _reference_freed(spec) -> tuple[str, ...]:
        """The declared reference parameters the runs do not determine on their own, freed with the candidate that
        reads them (judged with it: at one cold temperature only ``b_25 exp(a_v dT)`` shows, so both the 25 degC
        drag and the coefficient are held, as the coefficient was while the 25 degC drag was fitted; runs at two
        cold temperatures determine both)."""
        return tuple(n for n in spec.reference if n in ref_held)
    base_priors: dict[str, tuple[float, float]] = {}  # the base corrections' priors (kept in every later fit)

    def job(label, effs, free, pset, data, prior=True, profile=None, spec=None, lift=()):
        # priors on the declared uncertain parameters and the base corrections only: a candidate's values are seeds
        pri = {n: v for n, v in base_priors.items() if n in free and n not in lift}
        judge = {}
        if spec is not None and not profile:
            for n in spec.free + spec.second_stage + _reference_freed(spec):
                if n in uncertain or n in base_priors:
                    continue
                ref = spec.resolution.get(n) or max(abs(params.value(n)), abs(spec.seeds.get(n, 0.0)),
                                                    plaus[spec.plausible[n]][0] if n in spec.plausible else 0.0)
                judge[n] = ref if ref > 0 else 0.01 * (params[n].max - params[n].min)
        return {"label": label, "effects": tuple(effs), "free": tuple(free), "params_toml": pset.to_toml(),
                "settings": id_settings(prior, [n for n in free + (spec.second_stage if spec is not None else ())
                                                if n not in uncertain and n not in pri], pri),
                "runs": data, "profile": dict(profile or {}), "judge": judge,
                "profile_fractions": dict(spec.profile_fractions) if spec is not None and profile else {},
                "hold_at": {n: (pset.value(n) if spec is not None and spec.start else params.value(n)) for n in judge}, "determination_z": st.determination_z,
                "alpha": st.alpha,
                "second_stage": tuple(spec.second_stage) if spec is not None and not profile else (),
                "second_stage_range_ends": tuple(spec.second_stage_range_ends) if spec is not None else (),
                "second_stage_reseed": tuple(spec.second_stage_reseed) if spec is not None else (),
                "second_stage_gate": {n: why for n in (spec.second_stage if spec is not None and not profile else ())
                                      if n in SECOND_STAGE_GATES and (why := SECOND_STAGE_GATES[n](pset, data))},
                "singular_hold": tuple(spec.singular_hold) if spec is not None and not profile else (),
                "absent": {n: zero_is_absent(spec.name, n) for n in judge}}

    for r in runs:
        for w in check_run_model(r, base_plant, mode="open_loop"):
            say(f"warning: {w}")
    say(f"fitting the declared model ({', '.join(declared) or 'level A'}): "
        f"{', '.join(uncertain) or 'no parameter free (the segment states only)'}")
    t0 = time.perf_counter()
    base = _run_jobs([job("base", declared, uncertain, params, fit_runs)], 1, None)[0]
    if "error" in base:
        raise ThsaError(f"trace: the declared model cannot be fitted: {base['error']}")
    if st.channel_weights == "base_residual":
        # each channel weighted by what the declared model leaves on it (never below its sensor noise); refit
        left = _residual_rms(base, runs)
        for c in noise:
            noise[c] = max(noise[c], left.get(c, 0.0))
        say("channel weights from the declared model's residual: "
            + ", ".join(f"{c} {noise[c]:.3g} (sensor {sensor_noise[c]:.3g})" for c in noise))
        base = _run_jobs([job("base", declared, uncertain, params, fit_runs)], 1, None)[0]
        if "error" in base:
            raise ThsaError(f"trace: the declared model cannot be fitted: {base['error']}")
    base_fit_time = time.perf_counter() - t0
    say(f"base fit: {base_fit_time:.1f} s")
    first = base
    current, cur_effects, cur_params, cur_free = base, declared, ParameterSet.from_toml(base["params_toml"]), uncertain
    added, rounds, cand_times, ambiguous = [], [], [], []
    use_base = st.base_corrections if st.base_corrections is not None else st.candidates is None
    base_doc = None
    at_plausible_bound: dict[str, str] = {}  # explainer parameter -> its effect, where the base correction hit the bound
    base_bounds: dict[str, tuple[float, float, str]] = {}  # explainer parameter -> (lo, hi, effect) while bounded
    base_step_refused: dict[str, str] = {}  # declared components detailed (or tried) in the base step -> its verdict
    slipping: dict[str, list[str]] = {}  # of those, the ones refused only for a no-back that would not hold -> why
    cur_sig: dict | None = None  # the signature of the current model's residual, where computed
    if use_base:
        say("base-correction step: constant-torque explainers, screw efficiencies and motor-side inertia within "
            "plausible magnitudes")
        windows_cache = {spec: {r.name: _window(spec, r, params) for r in runs} for spec in WINDOWS}
        refinements = [sp for sp in candidate_specs(declared, params, st.candidates)
                       if set(EFFECTS[sp.name].supersedes) & set(declared) and not sp.profile
                       and sum(int(w.sum()) for w in windows_cache[sp.window].values()) >= MIN_WINDOW_SAMPLES]
        if refinements:
            say("base step: the corrections fitted with and without the detailed "
                f"{', '.join(sp.name for sp in refinements)} (declared {', '.join(sorted({x for sp in refinements for x in EFFECTS[sp.name].supersedes}))})")
        bc = _base_correction(first, declared, uncertain, params, plaus, fit_runs, noise, st, job, say, refinements)
        base_doc = bc["doc"]
        if bc["accepted"]:
            base_priors.update(bc["priors"])
            current, cur_effects = bc["fit"], tuple(bc["effects"])
            cur_params = ParameterSet.from_toml(current["params_toml"])
            cur_free = tuple(bc["free"])
            base_bounds = bc["bounds"]
            detailed = _detail_declared(bc["refinements"], current, cur_effects, cur_free, fit_runs, noise, st,
                                        job, say, plaus, windows_cache, runs)
            base_doc["declared_components_detailed"] = [d["doc"] for d in detailed]
            kept = next((d for d in detailed if d["doc"]["accepted"]), None)
            for d in detailed:
                base_step_refused[d["doc"]["name"]] = d["doc"].get("reason") or "not kept"
                why_d = d["doc"].get("implausible_because") or []
                if not d["doc"]["accepted"] and why_d and all(reason_kind(w) == "holding" for w in why_d):
                    # refused as the rig's base only because its loaded disks would not hold: a finding, not a base
                    # (a worn no-back), offered in the rounds beside what else lets the screw slip (a pawl's play)
                    slipping[d["doc"]["name"]] = [str(w) for w in why_d]
                    d["doc"]["offered_as_finding"] = ("refused as the rig's base only because its loaded disks would "
                                                      "not hold: offered in the rounds as a finding (a no-back that "
                                                      "does not hold), beside what else lets the screw slip")
            if kept is not None:
                f = kept["fit"]
                added.append(kept["step"])
                base_doc["corrections_before_detail"] = base_doc.get("corrections")
                base_doc["corrections"] = bc["corrections_of"](f)
                say("base corrections with the detailed component: " + ", ".join(
                    f"{c['parameter']} = {c['value']:.4g}{' (at bound)' if c['at_plausible_bound'] else ''}"
                    for c in base_doc["corrections"]))
                base_doc["error_after"] = _channel_errors(f)
                current, cur_effects = f, tuple(f["effects"])
                cur_params = ParameterSet.from_toml(f["params_toml"])
                cur_free = tuple(f["free"])
            at_plausible_bound = _explainers_at_bound(current, base_bounds)
            cur_sig = _signature(current, runs, cur_params, plant_of(cur_effects, cur_params), st.signature,
                                 sensor_noise, st.speed_sensors)
            base_doc["signature_after"] = _signature_brief(cur_sig)
    windows_cache = {spec: {r.name: _window(spec, r, params) for r in runs} for spec in WINDOWS}
    # where the candidates are scored: outside the base's transients on data the declared model may not describe
    masks = score_masks(runs, st.signature.transient_time) if use_base and st.score_outside_transients else None

    def score_mask(window: str):
        return None if masks is None else masks.get(window)

    win_scored = {w: (windows_cache[w] if score_mask(w) is None else
                      {r: windows_cache[w][r] & score_mask(w)[r] for r in windows_cache[w]}) for w in WINDOWS}

    def window_of(window: str, fitted: ParameterSet) -> dict:
        """A candidate's scored window; one that depends on the fitted parameters (the cogging's resolved samples at
        its count) at ``fitted``."""
        if window not in FITTED_WINDOWS:
            return win_scored[window]
        mask = score_mask(window)
        return {r.name: _window(window, r, fitted) & (mask[r.name] if mask is not None else True) for r in runs}

    def judged_on(name: str, window: str, fitted: ParameterSet) -> tuple[dict | None, dict]:
        """(score mask, window) an effect is admitted and judged again on: a no-back that does not hold on every
        sample (it slips while the load changes and the screw accelerates, which the base's transients are: all of
        a drive-off load ramp, as in the base step), any other outside the base's transients."""
        if name in slipping:
            return None, windows_cache[window]
        return score_mask(window), window_of(window, fitted)

    hurt: set[str] = set()
    retry: dict | None = None  # the round to retry the skipped ones in: its number, their names, its candidates
    # the backward check (:mod:`thsa_control.trace.backward`): the found effects' bookkeeping, the fits of every
    # model met (a model without an effect is often one fitted before), what was removed and why
    found_info: dict[str, bw.Added] = {}
    fit_memo: dict[tuple, dict] = {bw.model_key(cur_effects, cur_free, cur_params): current}
    removed: list[dict] = []
    backward_cpu: list[float] = []

    def fit_jobs(jbs):
        out = _run_jobs(jbs, st.workers, say)
        backward_cpu.extend(f.get("cpu_s", 0.0) for f in out)
        return out

    def leave_one_out(test: list) -> dict:
        """name -> (fit without it, its job, the record of its admission criterion given the others)"""
        todo, out = [], {}
        for a in test:
            effs, free, pset = bw.reduced_model(a, cur_effects, cur_free, cur_params)
            jb = job(f"without {a.name}", effs, free, pset, fit_runs)
            key = bw.model_key(effs, free, pset)
            if key in fit_memo:
                out[a.name] = [fit_memo[key], jb]
            else:
                todo.append((a, key, jb))
        if todo:
            say(f"backward check: refitting without {', '.join(a.name for a, _, _ in todo)}")
        for (a, key, jb), f in zip(todo, fit_jobs([t[2] for t in todo])):
            if "error" not in f:
                fit_memo[key] = f
            out[a.name] = [f, jb]
        for a in test:
            f, jb = out[a.name]
            if "error" in f:
                out[a.name].append({"name": a.name, "round_added": a.round, "fails": [], "prelim": False,
                                    "error": f"the model without it cannot be fitted: {f['error']}"})
                continue
            constant = CANDIDATES.get(a.name) is not None and CANDIDATES[a.name].base_correction
            smask, win = judged_on(a.name, a.spec.window, cur_params)  # the samples that admitted it
            out[a.name].append(bw.judge_removal(
                a, current, f, noise=noise, mask=smask, window_mask=win,
                alpha=st.alpha, min_window_reduction=st.min_window_reduction,
                max_channel_increase=st.max_channel_increase, z=st.determination_z,
                robust=bool(use_base and st.robust_constant_torque and constant), robust_test=st.robust_test))
        return out

    def backward_check(after_round: int) -> list[dict]:
        """Judge the earlier found effects given the later ones; remove the weakest that fails, then judge all
        the others again; returns the records."""
        nonlocal current, cur_effects, cur_params, cur_free, base_bounds, at_plausible_bound
        records, everyone = [], False
        while True:
            subj = [found_info[e["name"]] for e in added if e["name"] in found_info and not e.get("implied_by")]
            if len(subj) < 2:
                break
            test = subj if everyone else subj[:-1]
            loo = leave_one_out(test)
            recs = [loo[a.name][2] for a in test]
            cands = [r for r in recs if r["prelim"]]
            if cands:
                say(f"backward check: calibrating {', '.join(r['name'] for r in cands)} on null runs")
                jobs_of = {}
                for r in cands:
                    red, jr = loo[r["name"]][:2]
                    jobs_of[r["name"]] = ({**jr, "params_toml": red["params_toml"], "free": tuple(red["free"])},
                                          job(f"with {r['name']}", cur_effects, cur_free, cur_params, fit_runs))
                bw.null_calibrate(cands, {r["name"]: loo[r["name"]][0] for r in cands}, jobs_of, fit_runs, noise,
                                  {r["name"]: judged_on(r["name"], found_info[r["name"]].spec.window,
                                                        cur_params)[0] for r in cands},
                                  st.seed + 2000 + 10 * after_round, st.null_factor, fit_jobs)
            for r in recs:
                r["kept"] = not r["fails"]  # a model without it that cannot be fitted: kept, said so
                r["after_round"] = after_round
                records.append({k: v for k, v in r.items() if k != "prelim"})
            failing = [r for r in recs if not r["kept"]]
            if not failing:
                break
            worst = min(failing, key=lambda r: r["holdout_chi2_drop"])
            a = found_info.pop(worst["name"])
            f = loo[a.name][0]
            later = [e["name"] for e in added if e["name"] in found_info and found_info[e["name"]].round > a.round]
            step = next(e for e in added if e["name"] == a.name and not e.get("implied_by"))
            gone_implied = [e for e in added if e.get("implied_by") == a.name and e["name"] not in f["effects"]]
            added[:] = [e for e in added if e is not step and not any(e is g for g in gone_implied)]
            removed.append({"name": a.name, "round_added": a.round, "removed_after_round": after_round,
                            "explained_by": later, "implied_removed": [e["name"] for e in gone_implied],
                            "holdout_chi2_drop_when_added": a.drop_when_added,
                            "holdout_chi2_drop_given_others": worst["holdout_chi2_drop"],
                            "chi2_threshold": worst["chi2_threshold"], "null_chi2_drop": worst.get("null_chi2_drop"),
                            "window_reduction_given_others": worst["window_reduction"], "why": worst["fails"],
                            "step": step})
            say(f"removed {a.name} after round {after_round}: no longer earns its place given "
                f"{', '.join(later) or 'the others'} (held-out chi2 drop {a.drop_when_added:.4g} when added, "
                f"{worst['holdout_chi2_drop']:.4g} given the others: {'; '.join(worst['fails'])})")
            current, cur_effects = f, tuple(f["effects"])
            cur_params, cur_free = ParameterSet.from_toml(f["params_toml"]), tuple(f["free"])
            if a.beyond_base:
                base_bounds.update({n: (*b, a.name) for n, b in a.rebound.items()})
            at_plausible_bound = _explainers_at_bound(current, base_bounds)
            everyone = True
        return records

    # why the search stopped (``stop`` in trace.json): the cap on found effects unless a round says otherwise
    stop: dict = {"reason": "cap", "detail": f"{st.max_effects} found effects (max_effects)"}
    # the found effects count (``found_info``: added in a round, not removed since), not the base step's detailed
    # declared component (what the base contains) nor an effect implied by a found one
    def counted() -> int:  # a declared component's detailed model, added in a round, is what the base contains
        return sum(1 for n in found_info if not set(EFFECTS[n].supersedes) & set(declared))

    while counted() < st.max_effects:
        retry_now, retry = retry, None
        hurt_skipped: list[str] = []
        specs = candidate_specs(cur_effects, cur_params, st.candidates)
        # any base correction at its plausible bound (an efficiency included: the explainers share one torque per
        # load sign and direction, so one at its bound saturates the set): the joint lift is fitted, and every
        # constant-torque correction still bounded is offered beyond its bound, each judged against the joint lift
        lifting = (lift_names(base_priors, cur_free)
                   if use_base and st.joint_lift and _any_at_bound(current, base_doc, base_priors, base_bounds) else [])
        offer_beyond = ({n: e for n, (_, _, e) in base_bounds.items()} if lifting else at_plausible_bound)
        # a base correction that ran to its plausible bound: the same effect, larger than a rig's base can be,
        # is a candidate of its own (its bound lifted to the parameter file's)
        specs += [dataclasses.replace(CANDIDATES[e], base_correction=False)
                  for e in dict.fromkeys(offer_beyond.values()) if e in CANDIDATES]
        if retry_now is not None:  # the same model: only the ones skipped in the round before are fitted
            specs = [sp for sp in specs if sp.name in retry_now["names"]]
        scorable, skipped = [], []
        profile_grids: dict[str, dict] = {}  # candidate -> {profiled parameter: the values searched}
        for spec in specs:
            win = windows_cache[spec.window]
            if sum(int(w.sum()) for w in win.values()) < MIN_WINDOW_SAMPLES:
                skipped.append({"name": spec.name, "reason": f"does not act on these runs (window '{spec.window}' empty)"})
            elif spec.name in base_step_refused and not found_info and spec.name not in slipping:
                # offered again once a found effect changed the model: the holding margin of the rig's no-back (its
                # static coefficients) is what keeps the screw still at a drive-off stop while the rotors ring on a
                # drive-train compliance; level A's ideal no-back holds the load torque exactly and lets the screw
                # slip back with each swing (docs/trace_notes.md, "A damping the stop chose")
                skipped.append({"name": spec.name, "reason": "the detailed model of a declared component, judged in "
                                                             f"the base step ({base_step_refused[spec.name]})"})
            elif use_base and spec.name in RESOLVES and RESOLVES[spec.name](params, runs):
                # with the base step only: a declared model of another rig's base leaves drags that vary along
                # the stroke (Stribeck at the reversals of a short stroke), which a short record's ripple fits
                skipped.append({"name": spec.name, "reason": RESOLVES[spec.name](params, runs)})
            elif spec.name in {r["name"] for r in removed}:
                r = next(r for r in removed if r["name"] == spec.name)
                skipped.append({"name": spec.name, "reason": f"removed after round {r['removed_after_round']} by the "
                                                             "backward check: no longer earns its place given "
                                                             f"{', '.join(r['explained_by']) or 'the others'}"})
            elif spec.name in hurt and not _shows_now(spec.name, cur_sig):
                skipped.append({"name": spec.name, "reason": f"made the held-out error worse in round {len(rounds)}"})
                hurt_skipped.append(spec.name)
            else:
                # a profiled parameter searched over the values the runs resolve (the cogging's period counts:
                # multiples of the pole count whose harmonic the record resolves outside the base's transients)
                grids = {n: PROFILE_GRIDS[n](cur_params, runs, *r, transient_time=st.signature.transient_time,
                                             segment_duration=st.segment_duration)
                         for n, r in spec.profile.items() if n in PROFILE_GRIDS}
                unresolved = [why for vals, why in grids.values() if not vals]
                prof = {n: ((min(grids[n][0]), max(grids[n][0])) if grids.get(n, ([], None))[0] else r)
                        for n, r in spec.profile.items()}
                empty = [f"{n} {lo:g}..{hi:g}" for n, (lo, hi) in prof.items() if not hi > lo and n not in grids]
                if unresolved:
                    skipped.append({"name": spec.name, "reason": "; ".join(unresolved)})
                elif empty:
                    skipped.append({"name": spec.name, "reason": "the runs resolve too few values to profile: "
                                                                 + ", ".join(empty)})
                else:
                    sp = dataclasses.replace(spec, profile=prof) if prof != dict(spec.profile) else spec
                    if grids:
                        profile_grids[sp.name] = {n: vals for n, (vals, _) in grids.items()}
                    scorable.append(sp)
        if not scorable and hurt_skipped and st.retry_hurt and retry_now is None:
            # every candidate left was skipped, some only for making the error worse on the model before the last
            # addition: they are fitted on this one (a round of its own) before the search stops
            say(f"no candidate left to score but {', '.join(hurt_skipped)}, skipped for making the error worse in the "
                "round before: fitted on this model before stopping")
            hurt = set()
            continue
        if not scorable:
            stop = {"reason": "nothing_to_score", "detail": "every candidate left was skipped: "
                    + "; ".join(f"{k['name']} ({k['reason']})" for k in skipped)}
            say("no candidate left to score: stop")
            break
        # the longest fits first, so that the workers finish together (profiled, then the structural effects)
        scorable.sort(key=lambda sp: (not sp.profile, sp.base_correction, -len(sp.free)))
        jobs, extra = [], {}  # extra: index of a job -> its fit from the unsaturated interior (lift.interior)
        for spec in scorable:
            lift = tuple(n for n in spec.free if n in offer_beyond)
            if lift:  # beyond its base correction
                effs = cur_effects
                pset = lifted_bounds(cur_params, params, lift)
                jobs.append(job(spec.name, effs, cur_free, pset, fit_runs, lift=lift))
                if lifting:  # the others restart inside their bounds: from the saturated fit they stay pinned
                    extra[len(jobs) - 1] = job(f"{spec.name} (interior start)", effs, cur_free,
                                               interior(pset, base_priors, lifting, keep=lift), fit_runs, lift=lift)
                continue
            req = [r for r in EFFECTS[spec.name].requires if r not in cur_effects]
            replaced = {x for e in req + [spec.name] for x in EFFECTS[e].supersedes}
            effs = resolve_effects(None, add=[e for e in cur_effects if e not in replaced] + req + [spec.name])
            pset = cur_params.replace({n: v for n, v in spec.seeds.items() if cur_params.value(n) == 0})
            start_read = None
            if spec.start:  # starting values read off the runs (a static screen), within the search bounds; a
                # parameter the fit then finds undetermined is held there, not at the file's value
                screen = STARTS[spec.start](pset, runs)
                read = {n: min(max(v, pset[n].min), pset[n].max) for n, v in screen.items() if n in pset}
                pset = pset.replace(read)
                if read:
                    start_read = {"rule": spec.start, "values": read, "why": getattr(screen, "why", "")}
                    if not rounds:  # said once: the screen reads the runs, the same in every round
                        say(f"{spec.name}: started where the runs put it ({spec.start}"
                            + (f": {start_read['why']}" if start_read["why"] else "") + "): "
                            + ", ".join(f"{n} = {v:.4g} {pset[n].unit}" for n, v in read.items()))
            if spec.profile:
                # a switch the model lacks distorts the declared fit (a missing pawl clearance drives the
                # retraction disk friction to 0): a profiled candidate restarts the declared parameters, and
                # centres their priors, at the parameter file's values
                pset = pset.replace({n: params.value(n) for n in uncertain})
            free = tuple(dict.fromkeys(cur_free + spec.free + _reference_freed(spec)))
            jobs.append({**job(spec.name, effs, free, pset, fit_runs, profile=spec.profile, spec=spec),
                         **({"profile_grid": profile_grids[spec.name]} if spec.name in profile_grids else {}),
                         **({"start_read": start_read} if start_read else {})})
            if lifting and spec.base_correction:  # a found constant torque, the explainers unsaturated too
                extra[len(jobs) - 1] = job(f"{spec.name} (interior start)", effs, free,
                                           interior(pset, base_priors, lifting), fit_runs, spec=spec)
        joint_jobs = []
        if lifting:  # the whole plausible set lifted together, from the bounded optimum and from the interior
            lp = lifted_bounds(cur_params, params, lifting)
            joint_jobs = [job("joint lift", cur_effects, cur_free, lp, fit_runs, lift=tuple(lifting)),
                          job("joint lift (interior start)", cur_effects, cur_free,
                              interior(lp, base_priors, lifting), fit_runs, lift=tuple(lifting))]
            eff = tuple(n for n in lifting if n in EFFICIENCY_EXPLAINER.free)
            if eff:  # the base's own load-proportional loss beyond the catalogue spread, the others bounded
                ep = lifted_bounds(cur_params, params, eff)
                joint_jobs += [job("efficiencies lifted", cur_effects, cur_free, ep, fit_runs, lift=eff),
                               job("efficiencies lifted (interior start)", cur_effects, cur_free,
                                   interior(ep, base_priors, lifting, keep=eff), fit_runs, lift=eff)]
        say(f"round {len(rounds) + 1}: scoring {len(jobs)} candidates ({', '.join(s.name for s in scorable)})"
            + (f"; {len(extra)} of them also from the unsaturated interior, and the joint lift of "
               f"{', '.join(lifting)}" if lifting else ""))
        idx_extra = list(extra)
        if retry_now is not None and joint_jobs and retry_now["lifting"] == tuple(lifting):
            reuse_joint, joint_jobs = retry_now["fits_joint"], []  # the same model: the same joint lift
        else:
            reuse_joint = None
        fits = _run_jobs(jobs + [extra[i] for i in idx_extra] + joint_jobs, st.workers, say)
        if reuse_joint is not None:
            fits = fits + reuse_joint
        fits, fits_extra, fits_joint = (fits[:len(jobs)], fits[len(jobs):len(jobs) + len(idx_extra)],
                                        fits[len(jobs) + len(idx_extra):])
        for i, fe in zip(idx_extra, fits_extra):
            fits[i] = better(fits[i], fe)
        scored = []
        for spec, f, jb in zip(scorable, fits, jobs):
            if "error" in f:
                scored.append({"name": spec.name, "error": f["error"], "significant": False, "score": None,
                               "error_reduction": {}})
                continue
            cand_times.append(f["time_s"])
            k = len(spec.free) + len(spec.profile)
            # at the fit's own values where the window depends on them (the cogging's count)
            smask, win = judged_on(spec.name, spec.window, ParameterSet.from_toml(f["params_toml"]))
            constant = CANDIDATES.get(spec.name) is not None and CANDIDATES[spec.name].base_correction
            adm = admission_tests(current, f, noise, k=k, alpha=st.alpha, mask=smask, window=win,
                                  channel=spec.channel, min_window_reduction=st.min_window_reduction,
                                  max_channel_increase=st.max_channel_increase,
                                  robust=bool(use_base and st.robust_constant_torque and constant),
                                  robust_test=st.robust_test)
            drop, thr, win_red, err_red, aic_drop, seg_win = (adm[x] for x in (
                "holdout_chi2_drop", "chi2_threshold", "window_reduction", "error_reduction", "aic_drop",
                "window_segments"))
            win_sys = adm["window_reduction_beyond_noise"]
            plausible, why = _plausibility(f, spec, plaus)
            current_offset = _current_offset_check(spec, f, cur_sig, cur_effects, offer_beyond, base_bounds, runs,
                                                   cur_params)
            if current_offset is not None and current_offset["explained"]:
                plausible = False
                why.append(current_offset_reason(current_offset))
            fault = None
            if spec.name in slipping:  # a no-back that does not hold: what the candidate finds, not a refusal
                held_why = [w for w in why if reason_kind(w) == "holding"]
                why = [w for w in why if reason_kind(w) != "holding"]
                plausible = not why
                if held_why:
                    fault = no_back_fault(held_why)
            at_file = _declared_detail_at_file_values(f, spec, declared, why, params)
            if at_file:  # the declared component in detail at the parameter file's values: what the base contains
                plausible, why = True, []
            for fail in (adm["channel_fail"], adm["all_samples_fail"], adm["aic_fail"]):
                if fail:
                    plausible = False
                    why.append(fail)
            prelim = adm["significant"] and adm["window_ok"] and plausible
            robust = adm["robust_fail"] is None
            prelim = prelim and robust
            period_test = (_repetition(current, f, spec, k, runs, noise, smask, st.alpha,
                                       2 * st.signature.position_bin)
                           if spec.name in PERIODS and st.periodic_repeat else None)
            if period_test is not None and not period_test["repeats"]:
                _local_structure(period_test, cur_sig)
            # judged (and a refusal reported) only where it decides: on a candidate that passes the other tests
            repeats = period_test is None or period_test["repeats"] or not prelim
            prelim = prelim and repeats
            scored.append({
                "name": spec.name, "score": drop / max(adm["holdout_chi2_before"], 1e-300), "holdout_chi2_drop": drop,
                # reported beside it: the drop over all held-out samples (the candidates' scored samples differ by
                # window; the order of what is explained compares this one, trace/backward.py)
                "holdout_chi2_drop_all_samples": adm["holdout_chi2_drop_all_samples"],
                "chi2_threshold": thr, "error_reduction": err_red, "window": spec.window, "window_reduction": win_red,
                "window_reduction_beyond_noise": win_sys, "aic_drop": aic_drop, "bic_drop": current["bic"] - f["bic"],
                **({"window_on_all_samples": adm["window_on_all_samples"]} if adm["window_on_all_samples"] else {}),
                "plausible": plausible, "implausible_because": why, "parameters": _params_out(f, spec),
                **({"fault": fault} if fault else {}),
                **_amplitude_out(f, spec),
                "fit_time_s": f["time_s"], "converged": f["converged"], "prelim": prelim, "_fit": f, "_job": jb,
                **({"starts": f["starts"]} if "starts" in f else {}),
                **({"start": jb["start_read"]} if jb.get("start_read") else {}),
                "not_determined": _held_out(f) + at_file,
                "holdout_segments": _holdout_segment_changes(current, f, noise),
                "window_segments": seg_win,
                **({} if robust else {"not_robust": adm["robust_fail"]}),
                **({"current_offset": current_offset} if current_offset is not None else {}),
                **({"too_few_segments": {**adm["robust_too_few_segments"],
                                         # one held-out segment in holdout_every: the steady constant-torque motion
                                         # outside the base's transients the test needs
                                         "window_s_needed": (adm["robust_too_few_segments"]["needed"]
                                                             * st.holdout_every * st.segment_duration)}}
                   if adm.get("robust_too_few_segments") else {}),
                **({"periodicity": period_test} if period_test is not None else {}),
                **({} if repeats else {"not_periodic": periodicity.describe(period_test)}),
                **({} if adm["window_ok"] else {"window_too_small": True}),
                **({"scored_outside_transients": True} if smask is not None else {}),
                "_mask": smask,
                "_win": win,
                **({"beyond_base_correction": True} if any(n in offer_beyond for n in spec.free) else {}),
                **({"profile": f["profile"]} if f.get("profile") else {}),
                "_noise": noise,
                "_spec": spec,
            })
        # calibrate the promising ones on a null run of the current model (same inputs, its own noise)
        # calibrate the promising ones on a null run, strongest first, a batch (one per worker, the strongest
        # physical one included) at a time until one passes: the weaker ones are not needed then
        promising = sorted([s for s in scored if s.get("prelim")], key=lambda s: -s["holdout_chi2_drop"])
        if promising:
            null = _null_runs(current, fit_runs, noise, st.seed + len(rounds))
            # the current model's own fit to the null run goes to the workers with the first batch of candidates'
            # null fits (each fit is independent of the others: the same results, without a core idling while
            # it ran alone in this process)
            base_job = [job("null base", cur_effects, cur_free, cur_params, null)]
            nbs: dict = {}
            todo = list(promising)

            def calibrate(batch, null=null, nbs=nbs):
                say(f"calibrating {', '.join(c['name'] for c in batch)} on a null run")
                null_fits = _run_jobs(base_job + [{**c["_job"], "label": f"null {c['name']}", "runs": null,
                                                   "free": tuple(c["_fit"]["free"]), "judge": {},
                                                   "params_toml": _held_params(c["_job"]["params_toml"], c["_fit"])}
                                                  for c in batch], st.workers, say)
                if base_job:
                    nbs["fit"] = null_fits.pop(0)
                    base_job.clear()
                for c, nf in zip(batch, null_fits):
                    c["null_chi2_drop"] = null_drop(nbs["fit"], nf, noise, c["_mask"])
                return [c for c in batch if beats_null(c["holdout_chi2_drop"], c["null_chi2_drop"], st.null_factor)]

            while todo:
                batch = todo[:max(st.workers, 2)]
                phys = next((c for c in todo if not _is_explainer(c)), None)
                if phys is not None and phys not in batch:
                    batch.append(phys)
                todo = [c for c in todo if c not in batch]
                passed = calibrate(batch)
                if passed:
                    # the ones the data cannot tell from the strongest that passed are calibrated too: the
                    # ambiguity rule reports them with their significance
                    top = max(passed, key=lambda c: c["holdout_chi2_drop"])
                    _rivals(top, [], st.alpha)
                    near = [c for c in todo if top["holdout_chi2_drop"] - c["holdout_chi2_drop"]
                            < top["_indistinct_below"]]
                    if near:
                        calibrate(near)
                    todo = [c for c in todo if c not in near]
                    break
            for c in todo:
                c["not_calibrated"] = "a stronger candidate passed its null calibration"
        for s in scored:
            if "error" in s:
                continue
            s["significant"] = bool(s["prelim"] and beats_null(s["holdout_chi2_drop"], s.get("null_chi2_drop"),
                                                               st.null_factor))
        fresh = list(scored)  # this round's own fits (a retry round's: the ones it retried)
        if retry_now is not None:  # decided with the round before's candidates, scored on the same model
            scored += retry_now["scored"]
        scored.sort(key=lambda s: -(s.get("holdout_chi2_drop") or -math.inf))
        joint = None
        if fits_joint:
            jf = better(fits_joint[0], fits_joint[1])
            cmask = score_mask(CANDIDATES["coulomb_friction"].window)
            singles = [s for s in scored if _is_explainer(s)]
            if len(fits_joint) > 2:  # the efficiencies lifted: a single lift of its own (the base, not an effect)
                ef = better(fits_joint[2], fits_joint[3])
                if "error" not in ef:
                    singles.append({"name": EFFICIENCY_LIFT, "holdout_chi2_drop": (
                        holdout_total(current, noise, cmask) - holdout_total(ef, noise, cmask)),
                        "parameters": {n: _param_entry(ef["estimates"][n]) for n in EFFICIENCY_EXPLAINER.free
                                       if n in ef["estimates"]}})
            if "error" not in jf:
                jf = {**jf, "_lifted": tuple(lifting)}
                nested = [x["name"] for x in singles if x.get("beyond_base_correction")] + [EFFICIENCY_LIFT]
                joint = joint_verdict(current, jf, singles, noise, cmask, len(lifting), st.alpha, nested)
                say(f"joint lift of {', '.join(lifting)}: held-out chi2 drop {joint['holdout_chi2_drop']:.4g} "
                    f"(threshold {joint['chi2_threshold']:.3g}); {joint['verdict']}")
                _gate_on_joint(scored, joint)
                _gate_weaker_physical(scored, joint, current, jf, noise, cmask, lifting, params, job, st, say)
            else:
                joint = {"error": jf["error"]}
        # a candidate that made the held-out error worse is not fitted again in the next round
        hurt = {c["name"] for c in fresh if "error" not in c and c["holdout_chi2_drop"] < 0}
        rounds.append({"round": len(rounds) + 1, "model": list(cur_effects), "skipped": skipped,
                       "candidates": [_public(s) for s in sorted(fresh, key=lambda s: -(
                           s.get("holdout_chi2_drop") or -math.inf))],
                       **({"joint_lift": joint} if joint else {}),
                       **({"retry": {"of_round": retry_now["round"], "fitted": list(retry_now["names"]),
                                     "decided_with": [c["name"] for c in retry_now["scored"]]}}
                          if retry_now is not None else {})})
        best = next((s for s in scored if s.get("significant")), None)
        if best is None:
            if hurt_skipped and st.retry_hurt:
                say(f"no candidate is significant; {', '.join(hurt_skipped)}, skipped for making the error worse "
                    "in the round before, fitted on this model before stopping")
                retry = {"round": len(rounds), "names": hurt_skipped, "scored": scored,
                         "lifting": tuple(lifting), "fits_joint": fits_joint}
                # a candidate is skipped only after a round that added one: the signature is the current model's
                rounds[-1]["signature_after"] = _signature_brief(cur_sig)
                continue
            stop = {"reason": "nothing_significant", "detail": f"round {len(rounds)}: no candidate is significant"}
            say("no candidate is significant: stop")
            break
        best, yielded = _physical_first(best, scored, st.window_tolerance, current, noise)
        if yielded:
            rounds[-1]["physical_first"] = {"chosen": best["name"], "over": yielded}
            say(f"{best['name']} explains as much inside its window as the constant-torque "
                f"{', '.join(yielded)}: the physical effect comes first")
        rivals = _rivals(best, [s for s in scored if s["name"] not in yielded], st.alpha)
        if best.get("_not_rivals"):
            rounds[-1]["not_rivals"] = best["_not_rivals"]
            say(f"{', '.join(r['name'] for r in best['_not_rivals'])}: held-out drop{'s' if len(best['_not_rivals']) > 1 else ''} "
                f"close to {best['name']}'s, but "
                + "; ".join(f"{r['name']} drops its own channel's ({r['channel']}) error by {100 * r['its_reduction']:.0f} %, "
                            f"{best['name']} by {100 * r['best_reduction']:.0f} %" for r in best["_not_rivals"])
                + ": another part of the residual, not a rival")
        if rivals:
            names_amb = [best["name"]] + [r["name"] for r in rivals]
            rounds[-1]["ambiguous"] = names_amb
            ambiguous.append({"round": len(rounds), "candidates": names_amb,
                              "holdout_chi2_drop": {s["name"]: s["holdout_chi2_drop"] for s in [best, *rivals]},
                              "indistinct_below": best["_indistinct_below"],
                              "holdout_iact": best.get("_holdout_iact")})
            say(f"{', '.join(names_amb)} explain the same part of the residual (held-out chi2 drops within "
                f"{best['_indistinct_below']:.3g}): none is named; stop")
            stop = {"reason": "ambiguous", "detail": f"round {len(rounds)}: " + ", ".join(names_amb)}
            break
        say(f"added {best['name']}: held-out chi2 drop {best['holdout_chi2_drop']:.4g} "
            f"(null {best.get('null_chi2_drop', float('nan')):.3g})")
        f = best["_fit"]
        step = {"name": best["name"], "parameters": best["parameters"],
                **({"amplitude": best["amplitude"]} if "amplitude" in best else {}),
                "error_reduction": best["error_reduction"],
                "aic_drop": best["aic_drop"], "bic_drop": best["bic_drop"], "score": best["score"],
                "window": best["window"], "window_reduction": best["window_reduction"],
                "window_reduction_beyond_noise": best.get("window_reduction_beyond_noise"),
                **({"window_on_all_samples": best["window_on_all_samples"]} if best.get("window_on_all_samples")
                   else {}),
                "holdout_chi2_drop": best["holdout_chi2_drop"],
                "error_before": _channel_errors(current), "error_after": _channel_errors(f),
                "segments_explained": _explained_regimes(current, f, runs),
                "not_determined": best["not_determined"],
                **({"start": best["start"]} if best.get("start") else {}),
                **({"beyond_base_correction": True} if best.get("beyond_base_correction") else {}),
                **({"fault": best["fault"]} if best.get("fault") else {}),
                **({"given_the_lift": best["given_the_lift"]} if best.get("given_the_lift") else {}),
                **({"profile": best["profile"]} if best.get("profile") else {})}
        if joint and "error" not in joint and joint["significant"] and not _is_explainer(best) \
                and best["_spec"].channel == "motor_speed":
            own = best.get("_own_on_constant_torques")
            if own is None:  # the gate did not score it (no single lift to weigh against)
                own = holdout_total(current, noise, cmask) - holdout_total(best["_fit"], noise, cmask)
            alts = not_ruled_out(own, joint, {c["name"]: c for c in scored})
            if alts:
                step["not_ruled_out"] = alts
                say(f"{best['name']}: the record does not rule out "
                    + ", ".join(a["name"] for a in alts["alternatives"])
                    + f" (held-out drops on the constant torques' samples at least its {own:.4g} less the carry gap "
                      f"{joint['carry_gap']:.3g})")
        if best.get("beyond_base_correction"):
            step["contribution"] = _contribution(best, f, base_bounds, cur_effects, fit_runs, noise, job,
                                                 win_scored[best["window"]], st, say)
        refines = [x for x in EFFECTS[best["name"]].supersedes if x in cur_effects]
        if refines:  # a detailed model of a declared component (the rig's no-back for the level's ideal one)
            step["refines_declared"] = refines
        added.append(step)
        # effects the added one needs come with it (noback_backlash pulls in noback_quadrant_friction)
        for r in best["_job"]["effects"]:
            if r not in cur_effects and r != best["name"]:
                spec_r = CANDIDATES.get(r)
                names_r = (spec_r.free if spec_r else ()) or tuple(EFFECTS[r].parameters)
                added.append({"name": r, "implied_by": best["name"],
                              "parameters": {n: _param_entry(f["estimates"][n]) for n in names_r
                                             if n in f["estimates"]},
                              "held_at_file_values": [n for n in names_r if n not in f["estimates"]],
                              "error_reduction": best["error_reduction"], "window": best["window"],
                              "window_reduction": best["window_reduction"],
                              "error_before": step["error_before"], "error_after": step["error_after"],
                              "not_determined": [], "aic_drop": None, "bic_drop": None, "score": None})
        step["round_added"] = len(rounds)
        new_effects = tuple(best["_job"]["effects"])
        lifted = set(best["_spec"].free) if best.get("beyond_base_correction") else set()
        found_info[best["name"]] = bw.Added(
            name=best["name"], spec=best["_spec"], round=len(rounds), job=best["_job"],
            k=len(best["_spec"].free) + len(best["_spec"].profile), drop_when_added=best["holdout_chi2_drop"],
            drop_when_added_all=best["holdout_chi2_drop_all_samples"],
            replaced=tuple(e for e in cur_effects if e not in new_effects),
            implied=tuple(r for r in new_effects if r not in cur_effects and r != best["name"]),
            rebound={n: base_bounds[n][:2] for n in lifted if n in base_bounds}, beyond_base=bool(lifted),
            freed=tuple(n for n in f["free"] if n not in cur_free))
        current, cur_effects = f, new_effects
        cur_params = ParameterSet.from_toml(f["params_toml"])
        cur_free = tuple(f["free"])
        fit_memo[bw.model_key(cur_effects, cur_free, cur_params)] = current
        # the explainers still bounded are re-judged on the new fit: one at its bound is offered beyond it
        base_bounds = {n: b for n, b in base_bounds.items() if n not in lifted}
        at_plausible_bound = _explainers_at_bound(f, base_bounds)
        if st.backward:
            checked = backward_check(len(rounds))
            if checked:
                rounds[-1]["backward"] = checked
        if st.refree_held:
            refit = _refree_held(added, best["name"], current, cur_effects, cur_free, cur_params, fit_runs, params,
                                 found_info, ref_held, job, say, st.workers)
            if refit is not None:
                rounds[-1]["held_refreed"], refit_fit = refit
                if refit_fit is not None:
                    current = refit_fit
                    cur_params, cur_free = ParameterSet.from_toml(current["params_toml"]), tuple(current["free"])
                    fit_memo[bw.model_key(cur_effects, cur_free, cur_params)] = current
                    at_plausible_bound = _explainers_at_bound(current, base_bounds)
        # once per round, on the model the backward check left
        cur_sig = _signature(current, runs, cur_params, plant_of(cur_effects, cur_params), st.signature, sensor_noise,
                             st.speed_sensors)
        rounds[-1]["signature_after"] = _signature_brief(cur_sig)
    order = _order_by_contribution(added, found_info, leave_one_out) if st.backward else None
    _final_values(added, current, found_info)
    t_weights = time.perf_counter()
    if st.weight_check and st.channel_weights == "sensor_noise":
        _weight_checks(added, current, cur_effects, cur_params, fit_runs, noise, st, job, say)
    t_weights = time.perf_counter() - t_weights
    t_every = time.perf_counter()
    every_doc, every_fit = (_every_segment_check(added, current, cur_effects, cur_free, cur_params, fit_runs, noise,
                                                 st, job, say) if st.every_segment_check else (None, None))
    final = _adopt_every_segment(added, current, every_fit, every_doc, st, say)
    t_every = time.perf_counter() - t_every
    sig_before = _signature(first, runs, ParameterSet.from_toml(first["params_toml"]), base_plant, st.signature,
                            sensor_noise, st.speed_sensors)
    # every change of ``current`` (the base step, an added effect, a removal) is followed by its signature
    sig_after = cur_sig if cur_sig is not None else _signature(current, runs, cur_params,
                                                               plant_of(cur_effects, cur_params), st.signature,
                                                               sensor_noise, st.speed_sensors)
    t_grid = time.perf_counter()
    if st.segment_rate_check and sig_after.get("second_grid"):
        sig_after = _segment_rate_check(sig_after, cur_effects, cur_params, plant_of(cur_effects, cur_params),
                                        fit_runs, runs, st, job, sensor_noise, say)
    t_grid = time.perf_counter() - t_grid
    if rounds and "signature_after" not in rounds[-1]:  # a round that added nothing leaves the model as it was
        rounds[-1]["signature_after"] = _signature_brief(sig_after)
    # unexplained: structure an unmodelled-but-declared base does not leave; a residual above noise with only the
    # regime dependences of a base mismatch (starts, stops, reversals, quadrant) is reported as base-like
    beyond = (beyond_base(rounds, cur_effects, base_doc if use_base else None, added, EFFICIENCY_LIFT)
              if st.joint_lift else {"status": "not_fitted", "why": "the joint lift is off (TraceSettings.joint_lift)"})
    current_proportional_is_base(sig_after, beyond)
    structured, base_like = split_remainder(sig_after)
    base_like += [{"variable": f"held-out residual above noise ({c}: {r:.2g} x)"}
                  for c, r in sig_after.get("residual_to_noise", {}).items() if r > st.signature.max_noise_ratio]
    separ = _separability_doc(runs, cur_effects, cur_params, base_doc, added, rounds, uncertain, plaus, say) \
        if use_base and base_doc is not None and base_doc.get("accepted") else None
    final_parameters = _final_parameters(final, params)
    holding = _holding_doc(runs, params, final_parameters, plaus, added)
    if holding["remainder"]:  # the record shows a slip no found fault carries: never "explained"
        structured.append({"variable": holding["remainder"], "kind": "no_back_slip", "significant": True})
    doc = {
        "format": TRACE_FORMAT,
        "datasets": [{"name": r.name, "csv": str(r.csv_path), "samples": int(len(r.time)),
                      "duration_s": r.duration_s, "speed_sensors": speed_sensor_intervals(r, st.speed_sensors),
                      "model_warnings": check_run_model(r, base_plant, mode="open_loop")}
                     for r in runs],
        "base_model": lvl if level is not None else None,
        "removed_effects": list(remove),
        "declared_effects": list(declared),
        "declared_from_runs": from_runs,
        "final_effects": list(cur_effects),
        "uncertain_parameters": list(uncertain),
        "declared_not_determined": declared_held,
        # the final model's parameters (what a user rebuilds it from: the parameter file with these values and
        # ``final_effects``), and the declared uncertain set's fit before the base step under a name that says so
        "final_parameters": final_parameters,
        "declared_fit_before_base_step": {n: v for n, v in first["estimates"].items()},
        "effects_added": added,
        "found_effects": [e["name"] for e in added],
        "effects_removed": removed,
        "order": order,
        "base_corrections": base_doc,
        "every_segment": every_doc,
        "error_before": _channel_errors(first),
        "error_after": _channel_errors(final),
        "error_by_regime_before": _regime_errors(first, runs),
        "error_by_regime_after": _regime_errors(final, runs),
        "unexplained": bool(structured),
        "ambiguous": ambiguous,
        "beyond_plausible_base": beyond,
        "separability": separ,
        "no_back_holding": holding,
        "residual_signature": {**sig_after, "structured": [t["variable"] for t in structured],
                               "base_like": [t["variable"] for t in base_like]},
        "residual_signature_before": sig_before,
        "candidates": rounds[0]["candidates"] if rounds else [],
        "rounds": rounds,
        "stop": stop,
        "noise_rms": sensor_noise, "channel_weights": {"rule": st.channel_weights, "rms": dict(noise)},
        "settings": _settings_dict(st),
        "timing": {"base_fit_s": base_fit_time, "candidate_fit_s": (float(np.median(cand_times)) if cand_times else None),
                   "total_s": time.perf_counter() - t_start,
                   "backward_fits": len(backward_cpu), "backward_cpu_s": float(sum(backward_cpu)),
                   "weight_check_s": t_weights, "every_segment_s": t_every, "segment_rate_check_s": t_grid},
    }
    return TraceResult(doc, {"before": first, "after": final})


def _holding_doc(runs, params: ParameterSet, final_parameters: Mapping, plaus: Mapping, added: list) -> dict:
    """Does the no-back hold (:mod:`thsa_control.trace.holding`): the record's drive-off stretches, the final
    model's margin on each side the runs load (the holding rule's loaded disk sets, and the sides tested with the
    drive off) and what the two say against the found effects."""
    observed = drive_off_holds(runs, params)
    sides = {"compressive" if HOLDING_COEFFICIENTS[n] > 0 else "tensile" for n in plaus["holding"][2]}
    sides |= {s["side"] for s in observed["stretches"]}
    margin = holding_margin(final_parameters, params, sorted(sides))
    return {"observed": observed, "margin": margin, **holding_finding(observed, margin, added)}


def _refree_held(added: list, given: str, current: dict, cur_effects, cur_free, cur_params: ParameterSet, fit_runs,
                 params: ParameterSet, found_info: dict, ref_held: Mapping, job: Callable, say: Callable,
                 workers: int = 1):
    """Free once more, on the model with ``given`` just added, the parameters an earlier effect's own fit held
    because its estimate was undecided (``stderr_if_free`` finite: the run had information on it, not enough given
    that model; a null direction, a profiled parameter or the effect just added are not tried), each judged by the
    rule that held it (:func:`scoring._undetermined`, against the same reference magnitude).  Returns None where
    nothing is tried, else ``(record, fit)``: the fit where it moved from its start, determines at least one of them
    and fits the training samples no worse (``adopted``), else None with ``why_not``; a determined one moves from its
    effect's ``not_determined`` to ``determined_later``.  ``workers``: the starts run side by side."""
    tried: dict[str, tuple[dict, dict]] = {}  # parameter -> (its effect's entry, its not_determined entry)
    for e in added:
        if e.get("implied_by") or e["name"] == given:
            continue
        spec = found_info[e["name"]].spec if e["name"] in found_info else CANDIDATES.get(e["name"])
        if spec is not None and set(spec.reference) & set(ref_held):
            # its parameters are defined at a reference condition the runs never reach (the 25 degC drag on a
            # cold-only record): only a product shows, and a later effect does not change that
            continue
        for h in e.get("not_determined", []):
            n = h["parameter"]
            if (h.get("stderr_if_free") is not None and "profile_set" not in h and n in cur_params
                    and n not in cur_free and n not in tried):
                tried[n] = (e, h)
    if not tried:
        return None
    names = tuple(tried)
    judge = {}
    for n, (e, _) in tried.items():
        spec = found_info[e["name"]].spec if e["name"] in found_info else CANDIDATES.get(e["name"])
        ref = ((spec.resolution.get(n) if spec is not None else None)
               or max(abs(params.value(n)), abs(spec.seeds.get(n, 0.0)) if spec is not None else 0.0))
        judge[n] = ref if ref > 0 else 0.01 * (params[n].max - params[n].min)
    jb = job(f"{', '.join(names)} freed again given {given}", cur_effects, tuple(cur_free) + names, cur_params,
             fit_runs)
    jb = {**jb, "judge": judge, "hold_at": {n: cur_params.value(n) for n in names},
          "absent": {n: zero_is_absent(tried[n][0]["name"], n) for n in names}}
    # two starts, the lower training error kept among the fits that moved: from the current fit's segment states
    # and from the states the fit finds itself (as every candidate's).  Each alone fails on one pawl record:
    # started from the current states, the trust region of rig_ratchet_backlash_lowgain's refit shrank to nothing
    # in 22 evaluations (xtol) with every parameter at its start (0.0043 "determined"; training chi2 4.747e5 ->
    # 4.739e5 from the states alone), from its own states it moves to 0.00466 (2.79e5); on rig_ratchet_backlash
    # the own states' fit ends at 6.4e5 against 7.8e4 before, the current states' at 7.0e4 (0.00450)
    starts = {"current_states": {**jb, "initial_states": current.get("segment_states"),
                                 "custom_states": current.get("custom_states")}} if current.get("segment_states") else {}
    starts["own_states"] = jb
    say(f"freeing again, given {given}: {', '.join(names)} (held as undecided when their effect was added)")
    fits = dict(zip(starts, _run_jobs(list(starts.values()), workers, None)))  # the starts side by side

    def moved(f: dict) -> bool:
        pairs = [(e["value"], e["init"]) for e in (f["estimates"].get(n) for n in f["free"])
                 if e is not None and e.get("init") is not None]
        return not pairs or any(v != i for v, i in pairs)

    base_rec = {"given": given, "tried": list(names), "determined": {}, "adopted": False,
                "starts": {k: (f"failed: {f['error']}" if "error" in f else
                               {"training_chi2": f["chisqr"], "moved": moved(f), "status": f.get("status")})
                           for k, f in fits.items()}}
    ok = {k: f for k, f in fits.items() if "error" not in f}
    if not ok:
        why = f"the refit failed from {'both starts' if len(fits) > 1 else 'its start'}: " + "; ".join(
            f"{k}: {f['error']}" for k, f in fits.items())
        say(f"  {why}: held as before")
        return {**base_rec, "why_not": why}, None
    went = {k: f for k, f in ok.items() if moved(f)}
    if not went:
        # no parameter moved from its start: a standard error there is no determination of the optimum
        why = "no parameter moved from its start (" + "; ".join(f"{k}: {f.get('status', '')}" for k, f in ok.items()) + ")"
        say(f"  {why}: held as before")
        return {**base_rec, "why_not": why,
                "training_chi2": {"before": current["chisqr"], "after": min(f["chisqr"] for f in ok.values())}}, None
    start, f = min(went.items(), key=lambda kv: kv[1]["chisqr"])
    base_rec["start"] = start
    # the rule that held it, as the fit applied it to its own free estimates (``determination``, from ``judge``); a
    # fit that leaves every freed parameter undecided keeps them free but marked (``undetermined``, no verdict), and a
    # finite estimate with a standard error of 142 on a 0.0048 coefficient is no determination (rig_cogging_steps)
    verdicts = {n: (f["estimates"].get(n) or {}).get("determination", "not determined") if n in f["free"]
                else "not determined" for n in names}
    determined = [n for n in names if verdicts[n] != "not determined"]
    worse = f["chisqr"] > current["chisqr"] * (1 + 1e-9)
    still = {n: ((f.get("held") or {}).get(n, {}).get("reason")
                 or (f["estimates"].get(n) or {}).get("undetermined", {}).get("reason")
                 or "not determined by the refit") for n in names if n not in determined}
    rec = {**base_rec, "still_held": still, "training_chi2": {"before": current["chisqr"], "after": f["chisqr"]}}
    if not determined or worse:
        why = "none determined" if not determined else "the refit fits the training samples worse"
        say(f"  {why}: held as before")
        return {**rec, "why_not": why}, None
    rec["adopted"] = True
    for n in determined:
        e, h = tried[n]
        est = _param_entry(f["estimates"][n])
        rec["determined"][n] = {"effect": e["name"], **est, "determination": verdicts[n]}
        e["not_determined"] = [x for x in e["not_determined"] if x is not h]
        e.setdefault("determined_later", []).append({**h, "determined_given": given, "value": est["value"],
                                                     "stderr": est.get("stderr"), "ci95": est.get("ci95")})
    say("  determined now: " + ", ".join(f"{n} = {rec['determined'][n]['value']:.4g} "
                                        f"{rec['determined'][n].get('unit', '')}" for n in determined))
    return rec, f


def _final_values(added: list, current: dict, found_info: Mapping) -> None:
    """Each found effect's parameters as the final model has them (``parameters_final``): an effect's entry holds its
    values when it was added, and the fits after it free its parameters again with the later effects (a drive-train
    compliance's damping, 17.6 N m s/rad when added on rig_drivetrain_compliance_exc, 2.7 once the no-back's
    holding margin keeps the screw still at the drive-off stop).  ``changed_after_added``: the parameters that moved
    by more than 2 combined standard errors (the run's own, :func:`weights.stderr_of`) and 10 %, with the effects added
    after it."""
    for e in added:
        if e.get("implied_by"):
            continue
        fin = {n: _param_entry(current["estimates"][n]) for n in e.get("parameters", {})
               if n in current["estimates"] and not current["estimates"][n].get("held")}
        if not fin:
            continue
        e["parameters_final"] = fin
        _put_amplitude_final(e, current)
        moved = []
        for n, p in fin.items():
            a = e["parameters"][n]
            sa, sb = wt.stderr_of(a), wt.stderr_of(p)  # the weight check's errors (one rule for both)
            if a.get("held") or sa is None or sb is None:
                continue
            if wt.moved(a["value"], sa, p["value"], sb, 2.0):
                moved.append(n)
        if moved:
            rnd = found_info[e["name"]].round if e["name"] in found_info else 0
            e["changed_after_added"] = {"parameters": moved, "with": [
                x["name"] for x in added if not x.get("implied_by") and x["name"] in found_info
                and found_info[x["name"]].round > rnd]}


def _put_amplitude_final(e: dict, fit: dict) -> None:
    """A cosine and sine pair's amplitude as the final model ``fit`` has it (``amplitude_final``, the form of
    ``amplitude``, which stays the one when the effect was added): the size of a ripple is what a user reads off the
    final model, and the fits after it (the every-segment fit, the later effects) move it like any other value."""
    amp = _amplitude_out(fit, CANDIDATES[e["name"]]).get("amplitude") if e["name"] in CANDIDATES else None
    if amp is None:
        e.pop("amplitude_final", None)
    else:
        e["amplitude_final"] = amp


def _declared_detail_at_file_values(fit: dict, spec: CandidateSpec, declared, why: list,
                                    params: ParameterSet) -> list[dict]:
    """The detailed model of a declared component (the rig's no-back for level A's ideal one) whose only refusal is
    that the run determines none of its coefficients: what it explains is the component's structure (the disks'
    holding margin at a drive-off stop), not fitted values, so it stands at the parameter file's values (``params``),
    each reported as not determined.  Empty where that is not the case, or where the fit left a coefficient away
    from the file's value."""
    if not why or not set(EFFECTS[spec.name].supersedes) & set(declared) or any(w.kind != "undetermined" for w in why):
        return []
    if any(abs(fit["estimates"][n]["value"] - params.value(n)) > 1e-6 * max(abs(params.value(n)), 1e-12)
           for n in spec.free if n in fit["estimates"]):
        return []
    held = {h["parameter"] for h in _held_out(fit)}
    return [{"parameter": n, "held_at": fit["estimates"][n]["value"], "unit": fit["estimates"][n]["unit"],
             "reason": "the run determines none of the declared component's coefficients: the detailed model at the "
                       "parameter file's values", "value_if_free": None, "stderr_if_free": None}
            for n in spec.free if n in fit["estimates"] and n not in held]


def _checked_steps(added: list, current: dict) -> list[tuple[int, tuple[str, ...]]]:
    """``(index, names)`` of each found effect (not an implied one) with parameters the final fit ``current``
    estimated with a standard error (:func:`weights.checked_parameters`): what the weight and every-segment checks
    fit again."""
    steps = [(i, wt.checked_parameters(e, current)) for i, e in enumerate(added) if not e.get("implied_by")]
    return [(i, names) for i, names in steps if names]


def _put_range(step: dict, name: str, key: str, rng) -> None:
    """A range (``key``: ``range_over_channel_weights``, ``range_over_segment_sets``) on the parameter's entry as
    added and as the final model has it: the range is about the final model's estimate."""
    for which in ("parameters", "parameters_final"):
        if name in step.get(which, {}):
            step[which][name][key] = rng


#: the every-segment fit's tries in all when the evaluation limit stops it (each from where the last stopped)
EVERY_SEGMENT_FITS = 3


def _segment_rate_check(sig: dict, cur_effects, cur_params: ParameterSet, plant, fit_runs, runs, st,
                        job, sensor_noise: Mapping[str, float], say) -> dict:
    """The harmonics an angle test of ``sig`` (the final signature) left out because they are in step with the fit
    segments, tested on a second grid: the final model (``cur_effects`` at ``cur_params``) fitted again with the
    segment states only on segments of ``sig["second_grid"]["segment_s"]``, where they are not in step
    (:func:`~thsa_control.trace.signature.second_grid_ratio`), and its residual's dependence on those harmonics
    alone, given its levels, the model's own harmonics and the second grid's own (:func:`~thsa_control.trace.
    signature.harmonics_test`).  A pattern of every segment (a segment start state's error decaying alike in each)
    moves with the grid; a periodic torque stays at its harmonic.  Each such test gets ``segment_rate_check``; a
    significant one makes the test significant (``flagged_by``: each part at the angle test's level, so the
    test's family-wise level is at most twice it).  ``not_tested`` keeps only the harmonics still untested (in
    step on both grids, or the fit failed).  Returns the signature so updated."""
    grid = sig["second_grid"]
    length = float(grid["segment_s"])
    say(f"the angle tests' harmonics at the segment rate "
        f"({'; '.join(f'{n} {h}' for n, h in grid['harmonics'].items())}): the final model's segment states fitted "
        f"again on {length:.3g} s segments")
    jb = job(f"segment states on {length:.3g} s segments", cur_effects, (), cur_params, fit_runs)
    jb = {**jb, "settings": dataclasses.replace(jb["settings"], segment_duration=length)}
    f2 = _run_jobs([jb], 1, say)[0]
    only = {}
    if "error" not in f2:
        only = _signature(f2, runs, cur_params, plant, st.signature, sensor_noise,
                          st.speed_sensors, harmonics_only=grid["harmonics"])["harmonics_only"]
    else:
        say(f"the second grid's fit failed: {f2['error']}; those harmonics stay untested")
    tests = list(sig["tests"])
    left: dict[str, list[int]] = {}
    for t in tests:
        hs = grid["harmonics"].get(t["variable"])
        if not hs or t.get("kind") != "periodic":
            continue
        chk = only.get(t["variable"])
        if chk is None:  # its not_tested entry stands as the first grid's
            t["segment_rate_check"] = {"segment_s": length, "harmonics": [], "untested": list(hs),
                                       "why": f2.get("error") or "fewer than 50 samples or a revolution left"}
            continue
        t["segment_rate_check"] = {"segment_s": length, **chk}
        left[t["variable"]] = [h for h in hs if h not in chk["harmonics"]]
        if chk["significant"] and not t["significant"]:
            t["significant"] = True
            t["flagged_by"] = (f"harmonic{'s' if len(chk['harmonics']) > 1 else ''} "
                               f"{', '.join(str(h) for h in chk['harmonics'])} on {length:.3g} s segments "
                               f"(p {chk['p_value']:.2g})")
        say(f"{t['variable']} at harmonic{'s' if len(chk['harmonics']) > 1 else ''} "
            f"{', '.join(str(h) for h in chk['harmonics'])} on {length:.3g} s segments: "
            f"{', '.join(f'{1e3 * a:.2g}' for a in chk['amplitudes'])} mN m, p {chk['p_value']:.2g}"
            f"{' (significant)' if chk['significant'] else ''}")
    tests.sort(key=lambda d: not d["significant"])  # stable: the significant ones first, each kind in its order
    not_tested = []
    for d in sig.get("not_tested", []):
        name = d.get("variable")
        if name in left and d.get("harmonics") is not None:
            if not left[name]:
                continue
            d = {**d, **_segment_rate_not_tested(name, left[name], d["segment_s"], length)}
        not_tested.append(d)
    return {**sig, "tests": tests, "not_tested": not_tested}


def _every_segment_check(added: list, current: dict, cur_effects, cur_free, cur_params: ParameterSet, fit_runs,
                         noise: Mapping[str, float], st, job, say) -> tuple[dict | None, dict | None]:
    """The final model fitted again on every segment, the held-out ones too, from its values, with its free set and
    priors (:attr:`TraceSettings.every_segment_check`).  A found effect's parameter that the fit determines and
    moves beyond 2 combined standard errors (the run's own) and 10 % (:func:`weights.compare`, the weight check's
    rule) gets ``range_over_segment_sets`` on its final value (the hull of both fits' 95 % intervals): the
    segments held out of the search's fits decided it.  Every found effect's entry gets ``every_segment``
    (``parameters``: the every-segment fit's entries; ``moved``: the names that moved).  The final model's other
    fitted parameters (base corrections, the declared uncertain set) that move by the same rule go to the doc's
    ``moved_other`` (name -> both entries and the range).  Only a sound fit is read: one that converged and whose
    noise-weighted error over every sample is not above the search's last fit's (it starts at that fit's values,
    segment states and pawl clearances, so a higher one is a failed fit; started from the measured states it once
    went astray: rig_ratchet_backlash, 680716 against 130073); otherwise nothing is said to move and
    the doc says why.  Returns the doc's ``every_segment`` (the layout of the held-out segments, the names that
    moved, the fit's chi2 and convergence, ``sound``) and the fit (None where it failed or is not sound), or
    ``(None, None)`` where the final model has no parameter with a standard error."""
    steps = _checked_steps(added, current)
    in_steps = {n for _, names in steps for n in names}
    # the final model's other fitted parameters (base corrections, the declared uncertain set): their moves are
    # reported too, and with the fit adopted their final values are its
    others = [n for n in cur_free if n not in in_steps and n in current["estimates"]
              and not current["estimates"][n].get("held") and wt.stderr_of(current["estimates"][n]) is not None]
    if not steps and not others:
        return None, None
    # from the search's optimum, its segments' states included (the held-out ones fitted at its values) and the pawl
    # clearances its segments started with (tracked at that fit's initial values, not decision variables): started
    # from the measured states, or with the clearances tracked again at the search's values, the fit found other
    # optima, above the search's error over every sample (rig_cogging 4990 against 4176; rig_ratchet_backlash 680716
    # and, with the states only, 665856 against 130073)
    def every_job(label: str, pset: ParameterSet, start: dict) -> dict:
        """The final model's fit on every segment from ``pset`` and the fit ``start``'s segment starts."""
        jb = job(label, cur_effects, cur_free, pset, fit_runs)
        return {**jb, "settings": dataclasses.replace(jb["settings"], holdout_every=0),
                "initial_states": start.get("segment_states"), "custom_states": start.get("custom_states")}

    say("fitting the final model again on every segment, the held-out ones too")
    f = _run_jobs([every_job("every segment", cur_params, current)], 1, say)[0]
    fits = 1
    # it starts at the search's values, so a fit the evaluation limit stopped is still on its way (rig_loadpath_backlash
    # and rig_loadpath_preload took a second fit): it goes on from where it stopped, at most EVERY_SEGMENT_FITS fits
    # in all; a time budget or a solver failure is not retried
    while ("error" not in f and not f.get("converged") and fits < EVERY_SEGMENT_FITS
           and "function evaluations" in str(f.get("status", ""))):
        say(f"every-segment fit stopped at its evaluation limit ({st.max_nfev}); going on from where it stopped")
        nxt = _run_jobs([every_job(f"every segment ({fits + 1})", ParameterSet.from_toml(f["params_toml"]), f)], 1,
                        say)[0]
        fits += 1
        if "error" in nxt:
            break
        f = nxt
    if "error" in f:
        say(f"every-segment check not done: {f['error']}")
        return {"error": f["error"], "sound": False, "why": f"the fit failed: {f['error']}"}, None
    doc = {"moved": [], "moved_other": {}, "chisqr": f["chisqr"], "converged": f["converged"],
           "status": f.get("status"), "fits": fits, "holdout_layout": st.holdout_layout}
    why = f"the fit did not converge ({f.get('status')})" if not f.get("converged") else None
    if why is None:
        a = sum(_chi2_by_channel(current, noise, "all").values())
        b = sum(_chi2_by_channel(f, noise, "all").values())
        if not b <= a * (1 + 1e-9):
            why = f"its error over every sample ({b:.6g}) is above the search's last fit's ({a:.6g})"
    if why is not None:
        say(f"every-segment fit not read: {why}")
        return {**doc, "sound": False, "why": why}, None
    def move(n: str, who: str = ""):
        """The range both fits span where ``n`` moved (the weight check's rule, :func:`weights.compare`), said."""
        a, b = current["estimates"][n], f["estimates"][n]
        _, rng = wt.compare(a, {"every_segment": b}, st.determination_z, determined_only=False)
        if rng is not None:
            say(f"{who}{n} = {a['value']:.4g} on the training segments, {b['value']:.4g} on every segment (range "
                f"{rng[0]:.4g} .. {rng[1]:.4g}): the held-out segments' places decide it")
        return rng

    moved_all = []
    for i, names in steps:
        entry, moved = {}, []
        for n in (n for n in names if n in f["estimates"]):
            entry[n] = _param_entry(f["estimates"][n])
            rng = move(n, f"{added[i]['name']}: ")
            if rng is not None:
                moved.append(n)
                _put_range(added[i], n, "range_over_segment_sets", rng)
        added[i]["every_segment"] = {"parameters": entry, "moved": moved,
                                     "training": {n: _param_entry(current["estimates"][n]) for n in moved}}
        moved_all += moved
    moved_other = {}
    for n in (n for n in others if n in f["estimates"]):
        rng = move(n)
        if rng is not None:
            moved_other[n] = {"training": _param_entry(current["estimates"][n]),
                              "every_segment": _param_entry(f["estimates"][n]), "range": rng}
    return {**doc, "moved": moved_all, "moved_other": moved_other, "sound": True}, f


def _adopt_every_segment(added: list, current: dict, every: dict | None, every_doc: dict | None, st, say) -> dict:
    """The final model's fit: the every-segment fit ``every`` where :attr:`TraceSettings.final_on_every_segment`
    asks for it and :func:`_every_segment_check` found it sound; ``current`` (the search's last fit) otherwise.

    The held-out segments are there to decide which effects the model has; once that is decided, they are data
    like the others.  Left out of the values, they decide them wherever a test profile repeats a phase in the same
    segments (rig_drivetrain_compliance_rev: a reversal every 48 segments of 50 ms held its breakaway out of every
    fit; damping 0.42 N m s/rad on the training segments, 1.62 on every segment, rig-sim's 2).  Where adopted, each
    found effect's ``parameters_final`` are the every-segment fit's entries (ranges over weightings and segment sets
    kept); ``changed_after_added`` stays the search's (what the later effects moved).  ``every_doc`` gets
    ``adopted`` and, where not, ``why``."""
    if every_doc is None:
        return current
    if every is None or not st.final_on_every_segment:
        every_doc["adopted"] = False
        if every is not None:
            every_doc["why"] = "not asked (TraceSettings.final_on_every_segment = False)"
        else:
            say(f"final values stay the search's: {every_doc.get('why')}")
        return current
    every_doc["adopted"] = True
    for e in added:
        if e.get("implied_by") or "parameters_final" not in e:
            continue
        fin = {}
        for n, p in e["parameters_final"].items():
            q = every["estimates"].get(n)
            if q is None:
                fin[n] = p
                continue
            fin[n] = {**_param_entry(q), **{k: p[k] for k in ("range_over_channel_weights",
                                                              "range_over_segment_sets") if k in p}}
            w = fin[n].get("range_over_channel_weights")
            if w is not None and not w[0] <= fin[n]["value"] <= w[1]:
                # the weight check refitted the search's model from its values: its range is about the search's
                # estimate, and where the every-segment value lies outside it, it says nothing about that value
                fin[n]["range_over_channel_weights_training"] = fin[n].pop("range_over_channel_weights")
                say(f"{e['name']}: {n}'s range over the channel weights ({w[0]:.4g} .. {w[1]:.4g}) is about the "
                    f"search's value; the final value {fin[n]['value']:.4g} lies outside it")
        e["parameters_final"] = fin
        _put_amplitude_final(e, every)
        if "every_segment" in e:
            e["every_segment"]["adopted"] = True
    say("final values: the fit on every segment (the held-out segments decided the effects)")
    return every


def _weight_checks(added: list, current: dict, cur_effects, cur_params: ParameterSet, fit_runs, noise, st, job,
                   say) -> None:
    """Each found effect's parameters fitted again on the final model at the residual scales
    (:mod:`thsa_control.trace.weights`); the verdict goes to its ``effects_added`` entry as ``weight_check``, and a
    parameter whose estimate depends on the weights gets ``range_over_channel_weights``."""
    steps = _checked_steps(added, current)
    if not steps:
        return
    scales = wt.ml_channel_scales(noise, _residual_rms(current, fit_runs))
    if all(scales[c] <= noise[c] for c in noise):  # every channel at its noise: the same weights
        for i, names in steps:
            added[i]["weight_check"] = {"channel_scales": scales, "same_as_sensor_noise": True}
        return
    say("fitting the found effects' parameters again with the channels at their residual spread: "
        + ", ".join(f"{c} {scales[c]:.3g} ({scales[c] / noise[c]:.2g} x its noise)" for c in scales if noise[c]))
    # iteratively reweighted: each fit's own residual sets the next scales (the maximum-likelihood fixed point;
    # the final model's residual alone understates a channel whose error the effect's parameters absorbed)
    per = {i: dict(scales) for i, _ in steps}
    fits: dict = {}
    rounds_of = {i: 0 for i, _ in steps}
    todo = list(steps)
    for it in range(wt.MAX_REWEIGHTS):
        jobs = []
        for i, names in todo:
            jb = job(f"weights {added[i]['name']} ({it + 1})", cur_effects, names,
                     ParameterSet.from_toml(fits[i]["params_toml"]) if i in fits else cur_params, fit_runs,
                     prior=False, lift=names)
            jobs.append({**jb, "settings": dataclasses.replace(jb["settings"], noise=dict(per[i]))})
        nxt = []
        for (i, names), fw in zip(todo, _run_jobs(jobs, st.workers, say)):
            fits[i] = fw
            rounds_of[i] += 1
            if "error" in fw:
                continue
            new = wt.ml_channel_scales(noise, _residual_rms(fw, fit_runs))
            if wt.scales_settled(per[i], new):
                continue
            per[i] = new
            nxt.append((i, names))
        todo = nxt
        if not todo:
            break
    # the channels the model describes to their noise alone (where some are not and some are)
    structural = wt.structural_channels(scales, noise, st.signature.max_noise_ratio)
    kept = tuple(c for c in noise if c not in structural)
    alone: dict = {}
    if structural and kept:
        jobs = []
        for i, names in steps:
            jb = job(f"weights {added[i]['name']} (without {', '.join(structural)})", cur_effects, names, cur_params,
                     fit_runs, prior=False, lift=names)
            jobs.append({**jb, "settings": dataclasses.replace(jb["settings"], channels=kept)})
        alone = dict(zip([i for i, _ in steps], _run_jobs(jobs, st.workers, say)))
    for i, names in steps:
        alts = {"residual_scales": fits[i], **({"without_structural_channels": alone[i]} if i in alone else {})}
        # the scales reported (and the structural channels) are the final model's; the reweighted fit's are beside
        v = wt.weight_verdict(current, alts, names, scales, noise, st.determination_z, structural)
        added[i]["weight_check"] = {**v, "reweighted_scales": per[i], "fits": rounds_of[i] + (1 if i in alone else 0)}
        for n in v["depends_on_weights"]:
            _put_range(added[i], n, "range_over_channel_weights", v["range"][n])
            p = v["parameters"][n]
            say(f"{added[i]['name']}: {n} depends on the channel weights: " + "; ".join(
                f"{k.replace('_', ' ')} {e['value']:.4g}" for k, e in p.items()) +
                f" (range {v['range'][n][0]:.4g} .. {v['range'][n][1]:.4g})")


def _final_parameters(fit: dict, params: ParameterSet) -> dict:
    """Every parameter of the final model ``fit`` that differs from the parameter file ``params`` or that its last fit
    estimated: value (SI), unit, standard error and 95 % interval where estimated, and where it comes from (``fitted``:
    free in the last fit; ``held``: held at a value the run does not determine; ``set``: changed by an earlier step
    and not refitted).  With the file and ``final_effects`` this rebuilds the model whose errors are ``error_after``
    (:func:`final_model`)."""
    final = ParameterSet.from_toml(fit["params_toml"])
    est = fit.get("estimates") or {}
    out = {}
    for n in final.names:
        v = float(final.value(n))
        if n in est:
            e = est[n]
            out[n] = {**_param_entry(e), "value": v, "source": "held" if e.get("held") else "fitted"}
        elif n not in params or v != float(params.value(n)):
            out[n] = {"value": v, "stderr": None, "unit": final[n].unit, "source": "set"}
    return out


def final_model(doc: Mapping, params: ParameterSet | None = None) -> tuple[tuple[str, ...], ParameterSet]:
    """The final model of a trace (``trace.json``'s ``final_effects`` and ``final_parameters``) over the parameter
    file the trace read (default: the embedded actuator): the effects and the parameter set to build its plant.  A
    trace.json without them (written before ``final_parameters`` existed: its ``base_parameters`` were the declared
    set's fit before the base step, not the final model) is refused by name."""
    missing = [k for k in ("final_effects", "final_parameters") if k not in doc]
    if missing:
        raise ThsaError(f"trace.json: no {' and no '.join(missing)}: the final model cannot be rebuilt from this trace "
                        "(a trace written before final_parameters; its base_parameters are not the final model's)")
    p = params or default_parameters()
    return tuple(doc["final_effects"]), p.replace({n: e["value"] for n, e in doc["final_parameters"].items()})


#: the name the efficiencies lifted beyond their plausible spread go by among the joint lift's single lifts
EFFICIENCY_LIFT = "efficiencies beyond their catalogue spread (base)"


def _any_at_bound(current: dict, base_doc: dict | None, base_priors: Mapping, base_bounds: Mapping) -> bool:
    """A constant-torque or efficiency base correction at its plausible bound in ``current`` (the motor-side inertia
    carries no constant torque; an explainer already lifted is no longer bounded)."""
    if not base_doc:
        return False
    for n, e in (base_doc.get("explainers") or {}).items():
        if n not in base_priors or n in INERTIA_EXPLAINER.free or n not in current["estimates"]:
            continue
        if e["effect"] in EFFECTS and n not in base_bounds:
            continue  # lifted in an earlier round
        lo, hi = e["bound"]
        if _at_edge(current["estimates"][n]["value"], lo, hi, base_priors[n][0]):
            return True
    return False


def _current_offset_check(spec: CandidateSpec, f: dict, sig: dict | None, cur_effects, offer_beyond: Mapping,
                          base_bounds: Mapping, runs, cur_params: ParameterSet) -> dict | None:
    """A constant torque offered beyond its plausible bound on a record whose current reads an offset with the drive
    off (the signature's significant ``sensor_offset`` test): whether that offset's torque covers what the candidate
    finds beyond the bound (:func:`thsa_control.trace.separability.current_offset_torque`).  Measured: rig-sim's trim
    record with a 0.25 A offset on the primary current sensor (rig_current_offset), where an axial force of 6.1 kN
    [2.9, 9.3] was named beyond the base once the load path carried it (its LVDT term tipping the held-out drop to
    229 against the Coulomb drag's 208): Kt I0 = 0.081 N m at the motor, the force's excess over the 406 N bound at
    the interval's near end 0.089 N m.  None where the test did not find an offset or the candidate is no constant
    torque beyond a bound."""
    test = next((t for t in (sig or {}).get("sensors") or []
                 if t.get("kind") == "sensor_offset" and t.get("significant")), None)
    beyond = [n for n in spec.free if n in offer_beyond and n in base_bounds]
    if test is None or not beyond or "error" in f:
        return None
    vals = {n: v for n, v in _params_out(f, spec).items() if n in beyond and not v.get("held")}
    if not vals:
        return None
    return current_offset_torque(test, tuple(dict.fromkeys((*cur_effects, spec.name))),
                                 ParameterSet.from_toml(f["params_toml"]), vals,
                                 {n: tuple(base_bounds[n][:2]) for n in beyond}, runs, torque_constant(cur_params))


def current_offset_reason(c: Mapping) -> str:
    """The refusal text of a constant torque beyond the base that a current-sensor offset covers."""
    head = (f"the record's current reads {c['offset_A']:.3g} A with the drive off: with the drive on that offset is "
            f"a torque of Kt x {abs(c['offset_A']):.3g} A = {c['offset_torque']:.3g} N m of one sign at the motor "
            "that the model takes for motor torque, and ")
    est = c.get("estimate_excess_torque")
    if c["excess_torque"] <= 0.0 and est is not None:
        # the interval reaches back inside the bound: no excess the fit requires, only the estimate's
        return head + (f"this candidate is not beyond its plausible bound at the 95 % level (its interval reaches "
                       f"inside it; {est:.3g} N m at the motor beyond it at its estimate): what it finds is within "
                       f"{c['factor']:g} x the offset's torque, a current-sensor offset, not a drag or a force")
    return head + (f"what this candidate finds beyond its plausible bound, {c['excess_torque']:.3g} N m at the motor "
                   f"at least, is within {c['factor']:g} x that: a current-sensor offset, not a drag or a force")


def _gate_on_joint(scored: list[dict], joint: dict) -> None:
    """Constant torques judged against the joint lift (:func:`~thsa_control.trace.lift.joint_verdict`).

    A base correction offered beyond its bound is significant only when the whole plausible set lifted together
    passes its likelihood-ratio test and the candidate carries that drop.  Any constant torque (a lift or a found
    drag) is refused when the base's own efficiencies lifted beyond their catalogue spread explain as much as it
    (held-out drops within the carry gap): a rig whose load-proportional losses exceed the spread, such as a no-back
    that drags while driven, is a base, not an effect, and where both explain the same the record cannot tell a
    drag beyond the base from a lossier base."""
    d_eff = joint["single_drops"].get(EFFICIENCY_LIFT)
    for s in scored:
        if not (_is_explainer(s) and s.get("significant")):
            continue
        why = None
        if s.get("beyond_base_correction") and not joint["significant"]:
            why = "the base corrections lifted together do not pass their likelihood-ratio test"
        elif s.get("beyond_base_correction") and s["name"] not in joint["carriers"]:
            why = (f"does not carry the joint lift (held-out drop {s['holdout_chi2_drop']:.4g} against the joint "
                   f"{joint['holdout_chi2_drop']:.4g}, gap {joint['carry_gap']:.3g})")
        elif d_eff is not None and s["holdout_chi2_drop"] - d_eff < joint["carry_gap"]:
            why = (f"the base's efficiencies lifted beyond their catalogue spread explain as much (held-out drop "
                   f"{d_eff:.4g} against {s['holdout_chi2_drop']:.4g}, gap {joint['carry_gap']:.3g}): this record "
                   "cannot tell a constant torque beyond the base from a lossier base")
        if why:
            s["significant"] = False
            s["joint_lift_refused"] = why


def _gate_weaker_physical(scored: list[dict], joint: dict, current: dict, jf: dict, noise, cmask, lifting, params,
                          job: Callable, st, say: Callable) -> None:
    """Order by what is explained, against the joint lift (issue #21): a significant physical effect on the motor
    speed that explains less of the constant torques' samples than one of the round's single lifts (a constant torque
    beyond its plausible bound, or the lossier base) by more than the carry gap is named only where it adds to the
    lift: fitted together with the lifted set (started at the joint fit's values), its own window's held-out chi2 must
    drop below the joint fit's by more than its scaled ``chi2(k)`` threshold (:func:`scaled_threshold`).  Otherwise it
    is a weaker account of the base mismatch beyond the plausible set, which the record does not attribute, and it is
    refused (``joint_lift_refused``; the check in ``given_the_lift``).  Where it explains as much as the best lift,
    it is named first with what it does not rule out (:func:`~thsa_control.trace.lift.not_ruled_out`).

    Measured on a blind rig-sim check_cold record with a 4.9 / 0.7 N m direction drag planted (at one temperature a
    cold drag is a constant torque): the cold drag was named with a held-out drop of 1380 on those samples where the
    Coulomb drag, the axial force and the direction drag lifted dropped 1664 each and the lossier base 1649 (carry
    gap 78.5), all refused as constant torques the record cannot tell apart."""
    if not joint.get("significant") or not joint.get("single_drops"):
        return
    top_name, top = max(joint["single_drops"].items(), key=lambda kv: kv[1])
    gap = joint["carry_gap"]
    b0 = holdout_total(current, noise, cmask)
    weaker = []
    for s in scored:
        if "error" in s or not s.get("significant") or _is_explainer(s) or s["_spec"].channel != "motor_speed":
            continue
        own = b0 - holdout_total(s["_fit"], noise, cmask)
        s["_own_on_constant_torques"] = own  # read again for what a named effect does not rule out
        if top - own > gap:
            weaker.append((s, own))
    if not weaker:
        return
    lift = tuple(lifting)
    at_joint = {n: jf["estimates"][n]["value"] for n in lift if n in jf["estimates"]}
    joint_params = ParameterSet.from_toml(jf["params_toml"])
    jobs = []
    for s, _ in weaker:
        # two starts, the better kept (lift.better): the joint fit's optimum with the effect at its neutral value
        # (and the joint fit's segment states), and the effect's own optimum with the lifted set at the joint fit's
        # values (measured: from the second alone the fit stopped at its evaluation limit 20 x above the joint fit)
        name, free, effs, data = s["name"], tuple(s["_fit"]["free"]), s["_job"]["effects"], s["_job"]["runs"]
        neutral = {n: v for n, v in EFFECTS[name].neutral.items() if n in s["_spec"].free}
        from_joint = lifted_bounds(joint_params.replace(neutral), params, lift)
        from_own = lifted_bounds(ParameterSet.from_toml(s["_fit"]["params_toml"]), params, lift).replace(at_joint)
        jobs += [{**job(f"{name} with the joint lift", effs, free, from_joint, data, lift=lift),
                  "initial_states": jf.get("segment_states")},
                 job(f"{name} with the joint lift (from its own fit)", effs, free, from_own, data, lift=lift)]
    say(f"{', '.join(s['name'] for s, _ in weaker)}: explain{'s' if len(weaker) == 1 else ''} less of the constant "
        f"torques' samples than {top_name} lifted ({top:.4g}, carry gap {gap:.3g}): fitted with the joint lift")
    fits = _run_jobs(jobs, st.workers, say)
    for (s, own), pl in zip(weaker, (better(a, b) for a, b in zip(fits[::2], fits[1::2]))):
        check = {"lifted": list(lift), "own_drop_on_constant_torque_samples": own, "best_lift": top_name,
                 "best_lift_drop": top, "carry_gap": gap}
        if "error" in pl:  # no verdict from a failed fit: the effect stays, with what it does not rule out
            s["given_the_lift"] = {**check, "error": pl["error"]}
            say(f"{s['name']} with the joint lift: the fit failed ({pl['error']}); not judged against the lift")
            continue
        k = len(s["_spec"].free) + len(s["_spec"].profile)
        given = holdout_total(jf, noise, s["_mask"]) - holdout_total(pl, noise, s["_mask"])
        thr = scaled_threshold(pl, noise, s["_mask"], st.alpha, k)[0]
        s["given_the_lift"] = {**check, "holdout_chi2_drop": given, "chi2_threshold": thr, "adds": bool(given > thr)}
        if given > thr:
            continue
        s["significant"] = False
        s["joint_lift_refused"] = (
            f"explains less of the constant torques' samples than {top_name} (held-out drop {own:.4g} against "
            f"{top:.4g}, carry gap {gap:.3g}) and adds nothing to the joint lift (fitted with it, its window's held-out "
            f"drop {given:.4g} against {thr:.3g}): a weaker account of the base mismatch beyond the plausible set")
        say(f"{s['name']}: refused, {s['joint_lift_refused']}")


def _contribution(best: dict, f: dict, base_bounds: Mapping, cur_effects, fit_runs, noise, job, win, st,
                  say) -> dict:
    """What an effect named beyond its base correction contributes, the bounded part included (issue #21).

    The window drop of a lifted explainer (``window_reduction``) counts only what lies beyond the base correction's
    plausible bound: the bounded fit it is compared with already carries the effect up to the bound.  An engineer
    asks what the effect does to the error in all, and how much of it a plausible base would hold: the fitted model
    with the effect's value set to 0 and at the bound, every other parameter as fitted (the segment start states
    refitted, since they follow the data), against the model with all of it (:func:`~thsa_control.trace.lift.
    contribution`)."""
    spec = best["_spec"]
    n = next(x for x in spec.free if x in base_bounds)
    lo, hi, _ = base_bounds[n]
    v = f["estimates"][n]["value"]
    bound = hi if v >= 0 else lo
    p = ParameterSet.from_toml(f["params_toml"])
    jobs = [job(f"{best['name']} set to 0", cur_effects, (), p.replace({n: 0.0}), fit_runs),
            job(f"{best['name']} at its plausible bound", cur_effects, (), p.replace({n: bound}), fit_runs)]
    none, at_b = _run_jobs(jobs, st.workers, say)
    out = {"parameter": n, **contribution(f, none, at_b, noise, win, spec.channel, v, bound)}
    say(f"{best['name']}: its whole contribution drops the {spec.channel} window error by "
        f"{100 * (out.get('total_window_reduction') or math.nan):.0f} %, of which the plausible base correction "
        f"({bound:.4g}) would carry {100 * (out.get('bounded_window_reduction') or math.nan):.0f} %")
    return out


def _order_by_contribution(added: list, found_info: dict, leave_one_out) -> dict | None:
    """Reorder ``added`` in place: the base step's entries first, then the kept found effects by their leave-one-out
    held-out chi2 drop (largest first), each followed by the effects it implied; each found step gets
    ``leave_one_out``.  None when fewer than two found effects are kept (nothing to order)."""
    subj = [found_info[e["name"]] for e in added if e["name"] in found_info and not e.get("implied_by")]
    if len(subj) < 2:
        return None
    loo = leave_one_out(subj)
    contrib = {a.name: loo[a.name][2].get("holdout_chi2_drop_all_samples", -math.inf) for a in subj}
    steps = {e["name"]: e for e in added if e["name"] in found_info and not e.get("implied_by")}
    for a in subj:
        r = loo[a.name][2]
        steps[a.name]["leave_one_out"] = {k: r[k] for k in ("holdout_chi2_drop", "holdout_chi2_drop_all_samples", "chi2_threshold", "window_reduction",
                                                            "error_reduction", "aic_drop", "fails", "error")
                                          if k in r}
    ranked = sorted(subj, key=lambda a: -contrib[a.name])
    head = [e for e in added if not (e["name"] in found_info and not e.get("implied_by"))
            and e.get("implied_by") not in found_info]
    body = []
    for a in ranked:
        body.append(steps[a.name])
        body += [e for e in added if e.get("implied_by") == a.name]
    before = [a.name for a in subj]
    added[:] = head + body
    return {"measure": bw.ORDER_MEASURE, "order": [a.name for a in ranked], "order_of_addition": before,
            "changed": [a.name for a in ranked] != before,
            "contributions": [{"name": a.name, "round_added": a.round, "holdout_chi2_drop_given_others": contrib[a.name],
                               "holdout_chi2_drop_given_others_where_scored": loo[a.name][2].get("holdout_chi2_drop"),
                               "holdout_chi2_drop_when_added": a.drop_when_added_all,
                               "holdout_chi2_drop_when_added_where_scored": a.drop_when_added,
                               "window_reduction_given_others": loo[a.name][2].get("window_reduction")}
                              for a in ranked]}


def _separability_doc(runs, cur_effects, cur_params: ParameterSet, base_doc: dict, added: list, rounds: list,
                      uncertain, plaus: dict, say) -> dict | None:
    """What the record can tell apart among the constant-torque explainers (:mod:`~thsa_control.trace.separability`):
    the final model's base corrections, the detailed component's parameters and the declared uncertain set as what
    the model carries, the constant-torque candidates as what is asked about; reported, not used to select."""
    from .separability import explainer_steps, separability, separability_sentences

    base = {c["parameter"]: c["effect"] for c in base_doc.get("corrections", [])}
    for e in added:
        if e.get("refines_declared"):
            base.update({n: e["name"] for n in e.get("parameters", {})})
            base.update({h["parameter"]: e["name"] for h in e.get("not_determined", [])})
    base.update({n: "declared" for n in uncertain if n in cur_params})
    targets = {n: name for name, spec in CANDIDATES.items() if spec.base_correction and name in EFFECTS
               for n in spec.free if n in cur_params}
    # steps signed as the last fits found them (a direction drag acts one way only)
    fitted = {n: p["value"] for r in rounds for c in r["candidates"] for n, p in (c.get("parameters") or {}).items()
              if n in targets}
    mags = {}
    for spec in CANDIDATES.values():
        for n, rule in spec.plausible.items():
            if rule in plaus:
                mags[n] = plaus[rule][0]
    for n, rule in EFFICIENCY_EXPLAINER.plausible.items():
        mags[n] = plaus[rule][0]
    try:
        doc = separability(runs, cur_effects, cur_params, base, targets,
                           explainer_steps(cur_params, list(base) + list(targets), fitted, mags))
    except Exception as exc:  # noqa: BLE001 - a diagnostic that selects nothing: its failure is reported in
        # trace.json ("separability": {"error": ...}) and the progress, and the trace stands
        say(f"separability of the constant-torque explainers not computed: {type(exc).__name__}: {exc}")
        return {"error": f"{type(exc).__name__}: {exc}"}
    doc["sentences"] = separability_sentences(doc)
    for line in doc["sentences"]:
        say(line)
    return doc


def _residual_rms(fit: dict, runs) -> dict[str, float]:
    """RMS of a fit's residual per compared channel over all runs' samples (SI)."""
    acc: dict[str, list] = {}
    for r in runs:
        pr = fit["predictions"][r.name]
        for c, y in pr["measured"].items():
            e = np.asarray(y, float) - np.asarray(pr["simulated"][c], float)[:len(y)]
            acc.setdefault(c, []).append(e[np.isfinite(e)])
    return {c: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for c, v in acc.items() if sum(map(len, v))}


def parts_not_shown(fit: dict, spec: CandidateSpec, why: list) -> tuple[list, list]:
    """Split a declared component's detailed model's refusal reasons (:class:`~thsa_control.trace.scoring.Reason`,
    read by kind and parameter; a plain text never moves): ``(why, parts)``.

    The declared component is there by declaration: a coefficient of its detailed model that the run determines at
    zero (``determination == "zero"``) says that part of it does not show in this run (the light disk set's static
    hump on a rig whose light disk drags by other means), no verdict that the component is absent, provided another
    of its coefficients is determined away from zero (the component shows).  Those reasons move to ``parts``; with
    every determined coefficient at zero they stay (the detail would be a component without friction).

    A coefficient whose search bound is its zero says the same thing twice when the fit puts it there: "at its min
    bound" and "collapses to zero".  The bound is then no reason of its own and goes with the part (measured on a
    blind rig-sim record, the position loop with a cogging beside a drive-train compliance: the light disk's static
    coefficient at 1.9e-8 +- 0.001 N m/N, its bound 0, refused the detailed no-back in the base step, and a pawl
    clearance whose pitch the record did not determine was added in round 1 for the no-back it brings with it)."""
    est = {n: fit["estimates"].get(n) or {} for n in spec.free}
    zero = [n for n, e in est.items() if e.get("determination") == "zero" and not e.get("held")]
    shows = [n for n, e in est.items() if e.get("determination") == "determined" and not e.get("held")]
    if not zero or not shows:
        return list(why), []
    parts = [w for w in why if reason_kind(w) == "zero" and w.param in zero]
    at_zero = {w.param for w in parts if est[w.param].get("at_bound") == "min" and est[w.param].get("min") == 0.0}
    same = [w for w in why if reason_kind(w) == "bound" and w.param in at_zero]
    return [w for w in why if w not in parts and w not in same], parts


def _detail_declared(refinements, current: dict, cur_effects, cur_free, fit_runs, noise, st, job, say, plaus,
                     windows_cache, runs) -> list[dict]:
    """Judge each detailed model of a declared idealised component (fitted jointly with the base corrections) by
    the rules of a candidate: held-out chi2 drop above the ``chi2(k)`` quantile and ``null_factor`` times the drop
    the same refinement buys on a null run of the corrected base, window RMS drop, own channel not worse,
    plausible on the parameters the run determines (the others held at their file values); a coefficient the run
    determines at zero beside one it determines away from zero is a part not shown (:func:`parts_not_shown`),
    reported, no refusal."""
    out = []
    base_hold = holdout_total(current, noise)
    todo = []
    for spec, jb, f in refinements:
        d = {"name": spec.name, "refines": [x for x in EFFECTS[spec.name].supersedes if x in cur_effects],
             "accepted": False}
        if "error" in f:
            d["reason"] = f"fit failed: {f['error']}"
            out.append({"doc": d})
            continue
        # the candidates' admission test on every held-out sample, the window's own channel not worse
        adm = admission_tests(current, f, noise, k=len(spec.free), alpha=st.alpha, mask=None,
                              window=windows_cache[spec.window], channel=spec.channel,
                              min_window_reduction=st.min_window_reduction, max_channel_increase=st.max_channel_increase,
                              whole_record=False, aic=False)
        drop, thr, win_red = adm["holdout_chi2_drop"], adm["chi2_threshold"], adm["window_reduction"]
        why, absent_parts = parts_not_shown(f, spec, _plausibility(f, spec, plaus)[1])
        plausible = not why
        if adm["channel_fail"]:
            plausible = False
            why.append(adm["channel_fail"])
        d.update(holdout_chi2_drop=drop, chi2_threshold=thr, window=spec.window, window_reduction=win_red,
                 plausible=plausible, implausible_because=why, parameters=_params_out(f, spec),
                 not_determined=_held_out(f), holdout_segments=_holdout_segment_changes(current, f, noise),
                 error_reduction=adm["error_reduction"], parts_not_shown=absent_parts,
                 **({"window_on_all_samples": adm["window_on_all_samples"]} if adm["window_on_all_samples"] else {}),
                 **({"restart": f["restart"]} if f.get("restart") else {}))
        if adm["significant"] and adm["window_ok"] and plausible:
            todo.append((spec, jb, f, d))
        else:
            d["reason"] = "not significant" if plausible else "implausible: " + "; ".join(why)
            say(f"base step: {spec.name} not kept ({d['reason']}; held-out chi2 drop {drop:.4g}, window "
                f"drop {max(win_red.values(), default=0.0):.0%})")
        out.append({"doc": d, "fit": f, "spec": spec})
    if todo:
        null = _null_runs(current, fit_runs, noise, st.seed + 1000)
        say(f"calibrating {', '.join(t[0].name for t in todo)} on a null run of the corrected base")
        nfits = _run_jobs([job("null base", cur_effects, cur_free, ParameterSet.from_toml(current["params_toml"]), null)]
                          + [{**jb, "label": f"null {spec.name}", "runs": null, "free": tuple(f["free"]), "judge": {},
                              "params_toml": _held_params(jb["params_toml"], f)} for spec, jb, f, _ in todo],
                          st.workers, say)
        for (spec, jb, f, d), nf in zip(todo, nfits[1:]):
            nd = null_drop(nfits[0], nf, noise)
            d["null_chi2_drop"] = nd
            ok = beats_null(d["holdout_chi2_drop"], nd, st.null_factor)
            d["accepted"] = bool(ok)
            d["reason"] = ("significant: declared component detailed" if ok
                           else f"not significant against its null drop {nd:.3g}")
    # one detailed model per declared component: the one with the largest held-out drop among the accepted
    acc = [o for o in out if o["doc"]["accepted"]]
    if acc:
        best = max(acc, key=lambda o: o["doc"]["holdout_chi2_drop"])
        for o in acc:
            if o is not best:
                o["doc"]["accepted"] = False
                o["doc"]["reason"] = f"{best['doc']['name']} explains more"
        d, f = best["doc"], best["fit"]
        say(f"base step: declared component detailed: {d['name']} (held-out chi2 drop {d['holdout_chi2_drop']:.4g}, "
            f"null {d.get('null_chi2_drop', math.nan):.3g})"
            + "".join(f"; part not shown by this run: {w}" for w in d["parts_not_shown"]))
        best["step"] = {"name": d["name"], "parameters": d["parameters"], "error_reduction": d["error_reduction"],
                        "aic_drop": current["aic"] - f["aic"], "bic_drop": current["bic"] - f["bic"],
                        "score": d["holdout_chi2_drop"] / max(base_hold, 1e-300), "window": d["window"],
                        "window_reduction": d["window_reduction"], "holdout_chi2_drop": d["holdout_chi2_drop"],
                        "error_before": _channel_errors(current), "error_after": _channel_errors(f),
                        "segments_explained": _explained_regimes(current, f, runs),
                        "not_determined": d["not_determined"], "refines_declared": d["refines"],
                        "base_step": "declared component detailed",
                        **({"parts_not_shown": d["parts_not_shown"]} if d["parts_not_shown"] else {}),
                        **({"window_on_all_samples": d["window_on_all_samples"]} if d.get("window_on_all_samples")
                           else {})}
    return out


def _shows_now(name: str, sig: dict | None) -> bool:
    """The current model's residual is structured in the candidate's own angle (:data:`ANGLE_OF`): a candidate that
    made the held-out error worse in the round before is fitted again (measured on a rig-sim bipolar trim record with
    a ratchet backlash and a screw ripple: beside the backlash's error, 925355 in held-out chi2, the ripple lost 132
    in round 1 and was not fitted again, while the residual after the backlash was periodic in the screw angle)."""
    var = ANGLE_OF.get(name)
    return bool(var and sig and any(t.get("variable") == var for t in split_remainder(sig)[0]))


def _is_explainer(s: dict) -> bool:
    return bool(s.get("_spec") is not None and CANDIDATES.get(s["name"]) is not None
                and CANDIDATES[s["name"]].base_correction)


def _physical_first(best: dict, scored: list[dict], tol: float, current: dict, noise) -> tuple[dict, list[str]]:
    """Order by what is explained: when the best held-out drop is a constant-torque explainer's (a Coulomb or
    direction drag, an axial force) and a significant physical effect explains as much of the residual inside
    its own window, on its own channel (held-out RMS drop there at least the explainer's there, less ``tol``),
    the physical effect comes first; the explainers that yielded to it are returned (they are scored again in
    the next round).  On one load a no-back's aiding-quadrant friction is a direction drag; only the no-back
    says why."""
    if not _is_explainer(best):
        return best, []
    phys = [s for s in scored if s.get("significant") and not _is_explainer(s)]
    if not phys:
        return best, []
    p = max(phys, key=lambda s: s["holdout_chi2_drop"])
    spec = p["_spec"]
    win = p["_win"]  # every scored candidate carries the window it was scored on
    base = _chi2_by_channel(current, noise, "holdout", win).get(spec.channel, 0.0)
    if not base > 0:
        return best, []

    def red(s):
        return 1 - math.sqrt(_chi2_by_channel(s["_fit"], noise, "holdout", win).get(spec.channel, base) / base)

    if red(p) < red(best) - tol:
        return best, []
    return p, [s["name"] for s in scored if s.get("significant") and _is_explainer(s)
               and s["holdout_chi2_drop"] >= p["holdout_chi2_drop"]]


def _rivals(best: dict, scored: list[dict], alpha: float) -> list[dict]:
    """Plausible candidates whose held-out drop the data cannot tell from the best one's.

    Two fits differ by more than noise when their held-out chi2 differ by more
    than the ``chi2(1)`` quantile at ``alpha``, scaled by the best fit's reduced
    held-out chi2 when that exceeds 1 (the unmodelled part of the residual
    inflates every difference; a quasi-likelihood scaling).  On one speed and
    one load, for example, a constant force offset, a Coulomb friction and a
    direction-dependent friction are the same constant torque.
    """
    mask = best.get("_mask")  # the samples the drops were scored on
    gap, _, tau = scaled_threshold(best["_fit"], best["_noise"], mask, alpha, 1)
    best["_indistinct_below"] = gap
    best["_holdout_iact"] = tau
    # a constant torque whose drop a few held-out segments carry (``not_robust``) is no measure of what it explains;
    # against a constant-torque best, though, another constant torque that improves the typical held-out segment of
    # its window (median segment drop > 0: more segments better than worse) with the same pooled drop is the same
    # explanation, only less sure: naming the best would be a claim the data do not make (measured: on a run set
    # with an axial force planted, force_offset and direction_friction dropped 20557 / 20555, the force improving
    # 38 of 56 segments, sign test p 0.005 > alpha, and direction_friction was named)
    # Likewise a constant torque refused only because its own parameter is not determined or "collapses to zero":
    # with the same pooled drop as the best, its standard error is large because its torque is collinear with the
    # base corrections' (trace.json ``separability``), not because the data say it is absent (measured on
    # rig_direction_friction, round 2: coulomb_friction named with drop 168.4 while force_offset dropped 168.6,
    # "2.14e3 N collapses to zero (stderr 1.4e3)", and direction_friction 164.4, "not determined")
    def collinear_only(s):
        return bool(s["implausible_because"]) and all(
            reason_kind(w) in ("undetermined", "zero") for w in s["implausible_because"])

    def measured(s):
        if s.get("joint_lift_refused"):
            # refused against the joint lift of the base corrections: its drop is what the base's mismatch beyond the
            # plausible set buys, not a rival explanation (measured on rig_loadpath_preload, a load sweep: an axial
            # force beyond its bound dropped 63709 without carrying the joint lift, and as a rival it left the load
            # path, 4726, unnamed)
            return False
        if not s["plausible"] and not (_is_explainer(best) and _is_explainer(s) and collinear_only(s)):
            return False
        if not s.get("not_robust"):
            return True
        return _is_explainer(best) and (s.get("window_segments") or {}).get("median_drop", 0.0) > 0

    # one its own window test refuses (its window error drops by less than ``min_window_reduction``) explains too
    # little of what it is for to be named in the best's place: no rival (measured on a rig-sim load sweep with a
    # preloaded load path: a screw ripple that dropped 3.7 % of its window's motor-speed error, 4568 in held-out chi2,
    # left the load path, 4405 of 46 % of the LVDT's, unnamed); constant torques share one window, so among them the
    # window decides nothing the drops do not
    def large_enough(s):
        return not s.get("window_too_small") or (_is_explainer(best) and _is_explainer(s))

    # a periodic one whose gain comes from one place of the travel (``periodicity``) explains a local structure
    close = [s for s in scored if s is not best and "error" not in s and measured(s) and large_enough(s)
             and (s.get("periodicity") or {}).get("repeats", True)
             and best["holdout_chi2_drop"] - s["holdout_chi2_drop"] < gap]
    other = [s for s in close if _another_part(best, s)]
    best["_not_rivals"] = [{"name": s["name"], "channel": s["_spec"].channel,
                            "its_reduction": s["error_reduction"][s["_spec"].channel],
                            "best_reduction": best["error_reduction"][s["_spec"].channel]} for s in other]
    return [s for s in close if s not in other]


#: the share of a candidate's own-channel error drop the best one must give too for the two to explain the same part
SAME_PART_SHARE = 0.5


def _another_part(best: dict, s: dict) -> bool:
    """Whether ``s`` explains a part of the residual the best one leaves: on ``s``'s own channel
    (:attr:`CandidateSpec.channel`, where its effect shows) the best fit drops the held-out error by less than
    ``SAME_PART_SHARE`` of what ``s``'s drops it (both over all held-out samples).  Such a one is no rival however close
    the two held-out drops: naming the best leaves it its part, and the next round fits it on the best's model (the
    backward check removes the best where the second then explains its part too).  Measured on a rig-sim drive-train
    compliance under load reversals: the load path's compliance (the LVDT 19 % better, the screw speed 0 %) and the
    drive-train compliance (the screw speed 59 % better) were left ambiguous, their held-out drops 4361 and 623 within
    a gap of 4755 (reduced chi2 x IACT 6.8).  Constant torques share their channel (the motor speed) and stay rivals; a
    candidate whose own channel is not measured stays one."""
    ch = s["_spec"].channel
    mine, theirs = s.get("error_reduction") or {}, best.get("error_reduction") or {}
    if ch == best["_spec"].channel or ch not in mine or ch not in theirs or mine[ch] is None or theirs[ch] is None:
        return False
    return mine[ch] > 0 and theirs[ch] < SAME_PART_SHARE * mine[ch]


def _local_structure(test: dict, sig: dict | None) -> None:
    """Name, in a failed repetition test, the nut-position test's local structure of the current model's residual
    (:mod:`~thsa_control.trace.signature`) that lies in the period left out: what the candidate was fitted to.  A
    halves test (:func:`~thsa_control.trace.periodicity.halves_test`: a period too short to leave one out) leaves no
    period out and names none."""
    if "left_out" not in test:
        return
    a, b = test["left_out"]
    for t in (sig or {}).get("tests", []):
        pk = t.get("peak_bin")
        if t.get("kind") == "local" and t.get("significant") and pk and pk[1] >= a and pk[0] <= b:
            test["local_structure"] = {"variable": t["variable"], "peak_bin": list(pk), "p_value": t.get("p_value"),
                                       **({"law": t["law"]} if t.get("law") else {})}
            return


def _repetition(current: dict, fit: dict, spec: CandidateSpec, k: int, runs, noise, mask, alpha: float,
                min_period: float) -> dict:
    """The repetition test of an angle-periodic candidate (:func:`~thsa_control.trace.periodicity.repetition_test`):
    its held-out drop outside the one period of nut travel that carries most of it must pass the ``chi2(k)``
    quantile at ``alpha``, scaled as the ambiguity gap (:func:`_rivals`: the fit's reduced held-out chi2 and the
    held-out residual's IACT, a quasi-likelihood scaling of a structured remainder).

    Only for a period of ``min_period`` (two bins of the nut-position test) or more: a drag local on the scale
    the tracer resolves in nut position has no component at a shorter period (the binned profile's Nyquist
    period; a Gaussian bump of standard deviation s keeps exp(-2 pi^2 s^2 / P^2) of its amplitude at period P:
    6 % for s = 1.5 mm at 4 mm, nothing at a cogging's 0.01 mm), and leaving out one such period leaves out one
    held-out segment: it would test a segment, not a repetition (measured: a planted 18/rev cogging on a 2 s,
    0.15 mm/s rig-sim run, 6 steady held-out segments, lost: rest 9.4 against 17.7)."""
    params = ParameterSet.from_toml(fit["params_toml"])
    period = PERIODS[spec.name](params)
    thr, red, tau = scaled_threshold(fit, noise, mask, alpha, k)
    segs = periodicity.segment_drops(current, fit, noise, {r.name: nut_travel(r, params) for r in runs}, mask)
    if period < min_period:
        # No period can be left out (it is one held-out segment, or less), but the gain must still repeat over the
        # angle travel: each half of it (periodicity.halves_test) must pass the same scaled threshold.  The plain
        # held-out test cannot tell: a structured remainder (the base's drags at creep speed) projects on a sinusoid
        # fitted to the training segments that lie between the held-out ones, and the null calibration cannot see
        # that (its null run is the current model's own simulation, white noise only).
        out = periodicity.halves_test(segs, thr)
        out.update(period=period, reduced_chi2=red, iact=tau,
                   reason=f"period {period * 1e3:.3g} mm of nut travel, shorter than two bins of the nut-position "
                          f"test ({min_period * 1e3:.3g} mm): a drag local at the scale the tracer resolves has no "
                          "component at it; repetition not tested per period but over the two halves of the travel"
                          + (f" ({out['reason']})" if "reason" in out else ""))
        return out
    out = periodicity.repetition_test(segs, period, thr)
    out.update(reduced_chi2=red, iact=tau)
    return out


def _params_out(f: dict, spec: CandidateSpec) -> dict:
    out = {n: _param_entry(f["estimates"][n]) for n in (*spec.free, *spec.second_stage, *spec.profile)
           if n in f["estimates"]}
    for n, spread in spec.resolution.items():
        # a parameter with an assumed spread (the no-back's load share: 0.4..0.6 around the file's 0.5): where the run
        # determines it, say whether it lies inside the assumption (outside: reported, not refused: the value is the
        # rig's law seen through the model's; the assumption or the law wants a look).  The fit started it at the
        # file's value (``init``)
        e, p = f["estimates"].get(n), out.get(n)
        if e is None or p is None or p.get("held") or e.get("init") is None:
            continue
        lo, hi = e["init"] - spread, e["init"] + spread
        p["assumed_range"] = [lo, hi]
        p["outside_assumed_range"] = not lo <= p["value"] <= hi
    return out


def _explained_regimes(before: dict, after: dict, runs) -> dict:
    b, a = _regime_errors(before, runs), _regime_errors(after, runs)
    out = {}
    for reg, chans in b.items():
        for c, v in chans.items():
            w = a.get(reg, {}).get(c)
            if v and w is not None:
                out.setdefault(reg, {})[c] = 1 - w / v
    return out


def _public(s: dict) -> dict:
    return {k: v for k, v in s.items() if not k.startswith("_") and k != "prelim"}


def _settings_dict(st: TraceSettings) -> dict:
    d = {}
    for k, v in dataclasses.asdict(st).items():
        d[k] = list(v) if isinstance(v, tuple) else v
    return d
