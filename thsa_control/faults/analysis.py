"""Fault analysis: detection times, loads, displacements, recovery, false-alarm margins, sweeps.

Numbers only (frozen result dataclasses); ``report/faults.py`` draws and
writes them.  Every run is the closed loop with the monitors in it
(``sim/monitors.py``), on one *fault plant*: level D with the compliant drive train,
the torque limiter, the secondary load path, the jam, the brakes, the claw
stops and the standby motor, so that the normal scenarios (false alarms) and
the fault scenarios (detections) run on the same model.

* :func:`analyse_fault_case`: one fault scenario against the same scenario
  without its faults: detection time of each monitor (from the fault onset;
  inf: no trip), take-over and safing times, peak loads in each path after
  the fault, surface displacement after the fault, limiter slip, recovery
  time (speed error back within ``tolerance`` of the command for good), the
  energy balance residual.
* :func:`false_alarm_margins`: on each normal scenario, the largest level of
  each monitored quantity that persisted for the monitor's confirmation time
  (from the 1 ms output: resolution 1 ms), and the margin
  ``threshold / persisted level``.
* :func:`sweep_monitors`: thresholds scaled together and take-over delays
  varied: whether any normal scenario trips (closed-loop runs at each scale,
  exact at the control period) and the detection and recovery times of every
  fault scenario (channel failures on the rigid drive train in the report).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import ScenarioError
from ..model import build_plant
from ..sim.metrics import energy_residual  # noqa: F401 (one definition; re-exported here)
from ..sim.scenarios import SCENARIOS, Scenario, get_scenario
from ..sim.simulate import SimulationSettings, Simulator
from ..sim.monitor_settings import MonitorSettings

__all__ = [
    "FAULT_PLANT_EFFECTS", "RIGID_EFFECTS", "MONITORS", "FaultCase", "MonitorMargin", "SweepPoint", "FaultAnalysis",
    "normal_scenarios", "fault_scenarios", "analyse_fault_case", "recovery_time", "false_alarm_margins", "sweep_monitors",
    "analyse_faults", "energy_residual", "persisted_peak", "CASE_LABELS", "first_time_after",
]

FAULT_PLANT_EFFECTS = ("standby_motor", "drivetrain_compliance", "torque_limiter", "secondary_load_path", "surface_jam",
                       "motor_brakes", "claw_stops")
#: a rigid drive train for the switch-over figures (no limiter, no stick-slip limit cycle)
RIGID_EFFECTS = ("standby_motor", "motor_brakes")
#: monitor -> (trip signal, monitored signal, threshold field, confirmation field)
MONITORS = {
    "discrepancy": ("trip_discrepancy", "monitor_discrepancy", "discrepancy_threshold", "discrepancy_confirmation"),
    "lvdt": ("trip_lvdt", "monitor_lvdt", "lvdt_threshold", "lvdt_confirmation"),
    "speed": ("trip_speed", "monitor_speed_error", "speed_threshold", "speed_confirmation"),
}
_PEAKS = {"loadpath": "loadpath_force", "primary_attachment": "primary_attachment_force",
          "secondary_path": "secondary_path_force", "jam": "jam_force", "limiter_torque": "limiter_torque"}


def normal_scenarios() -> tuple[Scenario, ...]:
    """Scenarios without faults whose channel enables never change (no scheduled switch-over)."""
    return tuple(s for s in SCENARIOS.values() if not s.faults and s.monitors is None
                 and len(s.primary_enable) == 1 and len(s.standby_enable) == 1)


def fault_scenarios() -> tuple[Scenario, ...]:
    """Scenarios with scheduled faults."""
    return tuple(s for s in SCENARIOS.values() if s.faults)


def persisted_peak(time, signal, duration: float) -> float:
    """Largest ``L`` such that ``|signal| >= L`` over some window of ``duration`` [s] (sampled)."""
    t = np.asarray(time)
    q = np.abs(np.asarray(signal, dtype=float))
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    n = max(int(round(duration / dt)) + 1, 1)
    if n >= len(q):
        return float(np.min(q)) if len(q) else 0.0
    win = np.lib.stride_tricks.sliding_window_view(q, n)
    return float(np.max(np.min(win, axis=1)))


@dataclass(frozen=True)
class FaultCase:
    """One fault scenario's numbers (times from the first fault onset [s], forces [N], torques [N m at the screw]).

    Attributes
    ----------
    scenario : str
    faults : tuple of str
    fault_time_s : float
        Onset of the first fault [s].
    detection_s : dict
        Monitor -> delay of its trip after the onset (inf: no trip).
    takeover_s, safed_s : float
        Delay of the standby take-over and of the safing (inf: none).
    peaks : dict
        Path -> largest |force| (torque for ``limiter_torque``) after the onset;
        ``peaks_before`` the same before it.
    surface_displacement_m : float
        Surface position at the end minus at the onset.
    surface_excursion_m : float
        Largest |surface position - position at the onset| after it.
    limiter_slip_rad : float
        Slip angle of the limiter after the onset [rad at the screw].
    recovery_s : float
        From the onset until the moving average (``smooth_s``) of nut speed
        minus nut speed without the fault stays within ``tolerance`` x
        |command| (inf: never); nan when the run is safed (no recovery
        intended).  The average is needed at level D with the compliant drive
        train, whose aiding motion is a stick-slip limit cycle.
    peak_speed_error_m_s, peak_position_error_m : float
        Against the run without the fault.
    energy_residual : float
        Energy balance residual of the fault run (fraction of the throughput).
    final_motor_speed : float
        [rad/s] (0: the brakes hold the motors).
    series : dict
        Time series around the fault for the figures.
    """

    scenario: str
    faults: tuple[str, ...]
    fault_time_s: float
    detection_s: dict
    takeover_s: float
    safed_s: float
    peaks: dict
    peaks_before: dict
    surface_displacement_m: float
    surface_excursion_m: float
    limiter_slip_rad: float
    recovery_s: float
    peak_speed_error_m_s: float
    peak_position_error_m: float
    energy_residual: float
    final_motor_speed: float
    series: dict = field(repr=False, default_factory=dict)
    #: Which plant and take-over the case ran with, as the report names it ("fault plant", "rigid drive train", ...).
    label: str = "fault plant"
    #: What enabled the standby: ``"monitor"`` (the reconfiguration logic, flag ``standby_active``),
    #: ``"schedule"`` (the scenario's ``standby_enable`` input: the monitors' flag stays low) or ``""`` (no take-over).
    takeover_source: str = "monitor"

    @property
    def title(self) -> str:
        """``scenario [label]``: unique among the cases of a report."""
        return f"{self.scenario} [{self.label}]"

    @property
    def first_monitor(self) -> str:
        """The monitor that tripped first ("" if none)."""
        tripped = {m: t for m, t in self.detection_s.items() if math.isfinite(t)}
        return min(tripped, key=tripped.get) if tripped else ""


@dataclass(frozen=True)
class MonitorMargin:
    """False-alarm margin of one monitor on one normal scenario."""

    scenario: str
    monitor: str
    threshold: float
    persisted: float  # largest level held for the confirmation time (1 ms resolution)
    tripped: bool  # in the closed-loop run at the nominal thresholds

    @property
    def margin(self) -> float:
        """threshold / persisted level (inf when the quantity stays at 0)."""
        return self.threshold / self.persisted if self.persisted > 0 else math.inf


@dataclass(frozen=True)
class SweepPoint:
    """One point of the sweep: thresholds x ``scale``, take-over delay ``delay_s``."""

    scale: float
    delay_s: float
    normal_trips: tuple[str, ...]  # normal scenarios with a trip (false alarms)
    detection_s: dict  # fault scenario -> first trip after the onset (inf: missed)
    recovery_s: dict  # motor-fault scenario -> recovery time


@dataclass(frozen=True)
class FaultAnalysis:
    """Everything ``thsa faults`` reports.

    ``cases`` run on the fault plant (``effects``); ``rigid_cases`` are the
    channel-failure cases on level D with a rigid drive train (standby motor
    and brakes only), where the aiding motion has no stick-slip limit cycle,
    plus the papers' fixed 15 ms take-over (``*_papers_15ms``), for the
    comparison with the papers' switch-over figures.
    """

    level: str
    effects: tuple[str, ...]
    monitors: MonitorSettings
    cases: tuple[FaultCase, ...]
    margins: tuple[MonitorMargin, ...]
    sweep: tuple[SweepPoint, ...]
    normal_energy_residual: float
    tolerance: float
    smooth_s: float
    rigid_cases: tuple[FaultCase, ...] = ()

    def case(self, scenario: str) -> FaultCase:
        """The case of ``scenario``."""
        for c in self.cases:
            if c.scenario == scenario:
                return c
        raise KeyError(f"no fault case {scenario!r}; cases are {', '.join(c.scenario for c in self.cases)}")

    def min_margin(self, monitor: str) -> float:
        """Smallest false-alarm margin of ``monitor`` over the normal scenarios."""
        return min((m.margin for m in self.margins if m.monitor == monitor), default=math.inf)

    def report(self) -> str:
        """Cases by plant, false-alarm margins and sweep, as ``thsa faults`` prints."""
        from ..report.results import format_fault_analysis

        return format_fault_analysis(self)

    def to_dict(self) -> dict:
        """``faults.json`` (format ``thsa-faults/1``)."""
        from ..report.faults import fault_analysis_to_dict

        return fault_analysis_to_dict(self)

    def plot(self, ax=None):
        """Detection vs threshold scale and recovery vs take-over delay (the sweep); ``ax``: two Axes."""
        from ..report.faults import plot_sweep

        return plot_sweep(self, axes=ax)


def recovery_time(time, speed, speed_ref, command, t_fault: float, tolerance: float, smooth_s: float) -> float:
    """From ``t_fault`` until the ``smooth_s`` moving average of ``speed - speed_ref`` stays within
    ``tolerance`` x |command| for good [s] (0: never left; inf: never back)."""
    t = np.asarray(time)
    err = np.asarray(speed, dtype=float) - np.asarray(speed_ref, dtype=float)
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    n = max(int(round(smooth_s / dt)), 1)
    if n > 1:
        err = np.convolve(err, np.ones(n) / n, mode="same")  # centred average (no lag)
    band = tolerance * np.maximum(np.abs(np.asarray(command, dtype=float)), 1e-12)
    outside = np.flatnonzero((t >= t_fault) & (np.abs(err) > band))
    if outside.size == 0:
        return 0.0
    if outside[-1] >= len(t) - 1:
        return math.inf
    return float(t[outside[-1] + 1] - t_fault)


def first_time_after(time, mask, t0) -> float:
    """Time [s] from ``t0`` to the first sample where ``mask`` is set (inf when it never is)."""
    idx = np.flatnonzero(np.asarray(mask) > 0.5)
    return float(time[idx[0]] - t0) if idx.size else math.inf


def _simulator(params, level, effects, output_period):
    return Simulator(build_plant(level, effects, params=params), SimulationSettings(output_period=output_period))


def analyse_fault_case(scenario: Scenario | str, design, params, *, sim: Simulator | None = None,
                       monitors: MonitorSettings | None = None, tolerance: float = 0.05, smooth_s: float = 0.1,
                       level: str = "D", effects=FAULT_PLANT_EFFECTS, label: str = "fault plant") -> FaultCase:
    """Run a fault scenario and the same scenario without its faults; see :class:`FaultCase`.

    ``label`` names the plant and take-over of the case in reports (:attr:`FaultCase.title`).

    ``sim`` must have a 1-sample output (``output_period=None``) for the energy
    balance; by default one is built on the fault plant.
    """
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    if not sc.faults:
        raise ScenarioError(f"scenario {sc.name!r} has no faults to analyse")
    sim = sim or _simulator(params, level, effects, None)
    settings = monitors or sc.monitors or MonitorSettings()
    # the run, and the same run without faults and without scheduled switch-overs, in one batch
    run, ref = sim.run_batch([replace(sc, monitors=settings),
                              replace(sc, faults=(), monitors=settings, primary_enable=((0.0, sc.primary_enable[0][1]),),
                                      standby_enable=((0.0, sc.standby_enable[0][1]),))], design, params)
    t = np.asarray(run.time)
    t_f = min(f.time for f in sc.faults)
    after = t >= t_f
    detection = {m: first_time_after(t, run[sig[0]], t_f) for m, sig in MONITORS.items()}
    takeover = first_time_after(t, np.asarray(run["standby_active"]), t_f)
    takeover_source = "monitor" if math.isfinite(takeover) else ""
    if not math.isfinite(takeover):  # a take-over scheduled by the scenario (monitors without reconfiguration)
        scheduled = first_time_after(t, np.asarray(run["energised_standby"]) > 0.5, t_f)
        if math.isfinite(scheduled):
            takeover, takeover_source = scheduled, "schedule"
    safed = first_time_after(t, np.asarray(run["safed"]), t_f)
    peaks = {k: float(np.max(np.abs(run[s][after]))) for k, s in _PEAKS.items()}
    peaks_before = {k: float(np.max(np.abs(run[s][~after]))) if np.any(~after) else 0.0 for k, s in _PEAKS.items()}
    surf = np.asarray(run["surface_position"])
    i_f = int(np.argmax(after))
    h = run.info["output_period_s"]
    err_v = np.asarray(run["nut_speed"]) - np.asarray(ref["nut_speed"])
    err_x = np.asarray(run["nut_position"]) - np.asarray(ref["nut_position"])
    recovery = math.nan if math.isfinite(safed) else recovery_time(
        t, run["nut_speed"], ref["nut_speed"], ref["speed_cmd"], t_f, tolerance, smooth_s)
    window = (t >= t_f - 0.1) & (t <= t_f + 0.6)
    step = max(int(round(1e-3 / h)), 1)
    keep = np.flatnonzero(window)[::step]
    series = {n: np.asarray(run[n])[keep] for n in (
        "speed_cmd", "nut_speed", "surface_speed", "motor_speed", "screw_speed", "measured_motor_speed",
        "motor_current", "standby_current", "motor_torque", "limiter_torque", "limiter_slip_torque", "limiter_slipping",
        "loadpath_force", "primary_attachment_force", "secondary_path_force", "jam_force", "gimbal_displacement",
        "monitor_discrepancy", "monitor_speed_error", "trip_discrepancy", "trip_lvdt", "trip_speed", "standby_active",
        "safed", "brakes_engaged", "surface_position", "energised_standby")}
    series["time"] = t[keep]
    series["nut_speed_no_fault"] = np.asarray(ref["nut_speed"])[keep]
    return FaultCase(
        sc.name, tuple(f.label for f in sc.faults), float(t_f), detection, takeover, safed, peaks, peaks_before,
        float(surf[-1] - surf[i_f]), float(np.max(np.abs(surf[after] - surf[i_f]))),
        float(np.sum(np.abs(np.asarray(run["limiter_slip_speed"])[after])) * h), recovery,
        float(np.max(np.abs(err_v[after]))), float(np.max(np.abs(err_x[after]))), energy_residual(run),
        float(run["motor_speed"][-1]), series, label, takeover_source,
    )


def false_alarm_margins(design, params, *, scenarios=None, monitors: MonitorSettings | None = None,
                        sim: Simulator | None = None, level: str = "D", effects=FAULT_PLANT_EFFECTS):
    """Margins of each monitor on each normal scenario (closed loop, monitors active).

    Returns ``(margins, energy_residual)``: a tuple of :class:`MonitorMargin`
    and the largest |energy residual| of the normal runs (1 ms output: rough).
    """
    settings = monitors or MonitorSettings()
    sim = sim or _simulator(params, level, effects, 1e-3)
    out = []
    scenarios = tuple(scenarios or normal_scenarios())
    runs = sim.run_batch([replace(sc, monitors=settings) for sc in scenarios], design, params)
    for sc, run in zip(scenarios, runs):
        for m, (trip, sig, thr, conf) in MONITORS.items():
            out.append(MonitorMargin(sc.name, m, float(getattr(settings, thr)),
                                     persisted_peak(run.time, run[sig], getattr(settings, conf)),
                                     bool(np.any(np.asarray(run[trip]) > 0.5))))
    return tuple(out)


def _tripped(run) -> bool:
    return bool(any(np.any(np.asarray(run[sig[0]]) > 0.5) for sig in MONITORS.values()))


def _scaled(settings: MonitorSettings, scale: float, delay: float) -> MonitorSettings:
    return replace(settings, discrepancy_threshold=settings.discrepancy_threshold * scale,
                   lvdt_threshold=settings.lvdt_threshold * scale, speed_threshold=settings.speed_threshold * scale,
                   takeover_delay=delay)


def sweep_monitors(design, params, *, scales=(0.5, 0.75, 1.0, 1.5, 2.0), delays_s=(0.0, 0.005, 0.01, 0.02),
                   monitors: MonitorSettings | None = None, sim: Simulator | None = None, tolerance: float = 0.05,
                   smooth_s: float = 0.1, level: str = "D", effects=FAULT_PLANT_EFFECTS,
                   rigid_sim: Simulator | None = None) -> tuple[SweepPoint, ...]:
    """Closed-loop sweep of the thresholds (scaled together) and of the take-over delay.

    With ``rigid_sim`` the channel-failure scenarios run on it (a rigid drive
    train: no stick-slip limit cycle, recovery without averaging).
    """
    base = monitors or MonitorSettings()
    sim = sim or _simulator(params, level, effects, 1e-3)
    normals, faults = normal_scenarios(), fault_scenarios()
    motor = [s for s in faults if any(f.kind == "channel_failure" for f in s.faults)]
    motor_sim = rigid_sim or sim
    smooth_motor = 0.0 if rigid_sim is not None else smooth_s
    refs = dict(zip((s.name for s in motor),
                    motor_sim.run_batch([replace(s, faults=(), monitors=base) for s in motor], design, params)))
    points = []
    for scale in scales:
        # the runs of one scale, batched per simulator: the normal scenarios, and the fault scenarios at
        # each delay (the take-over delay matters only for channel failures)
        normal = sim.run_batch([replace(s, monitors=_scaled(base, scale, base.takeover_delay)) for s in normals],
                               design, params)
        trips = tuple(s.name for s, run in zip(normals, normal) if _tripped(run))
        cases = [(delay, s) for delay in delays_s for s in faults if s in motor or delay == delays_s[0]]
        results = {}
        for runner, mine in ((sim, [c for c in cases if c[1] not in motor]), (motor_sim, [c for c in cases if c[1] in motor])):
            if mine:
                got = runner.run_batch([replace(s, monitors=_scaled(base, scale, delay)) for delay, s in mine],
                                       design, params)
                results.update(zip(((delay, s.name) for delay, s in mine), got))
        for delay in delays_s:
            det, rec = {}, {}
            for s in faults:
                if s not in motor and delay != delays_s[0]:
                    continue  # the take-over delay matters only for channel failures
                run = results[(delay, s.name)]
                t = np.asarray(run.time)
                t_f = min(f.time for f in s.faults)
                trips_any = np.asarray(run["trip_discrepancy"]) + np.asarray(run["trip_lvdt"]) + np.asarray(run["trip_speed"])
                det[s.name] = first_time_after(t, trips_any, t_f)
                if s in motor:
                    ref = refs[s.name]
                    rec[s.name] = math.nan if np.any(np.asarray(run["safed"]) > 0.5) else recovery_time(
                        t, run["nut_speed"], ref["nut_speed"], ref["speed_cmd"], t_f, tolerance, smooth_motor)
            points.append(SweepPoint(float(scale), float(delay), trips, det, rec))
    return tuple(points)


#: Labels of the three kinds of cases of :func:`analyse_faults` (as the report and ``thsa faults`` print them).
CASE_LABELS = {"fault": "fault plant", "rigid": "rigid drive train",
               "papers": "rigid drive train, papers' fixed 15 ms take-over"}


def analyse_faults(design, params, *, monitors: MonitorSettings | None = None, scales=(0.5, 0.75, 1.0, 1.5, 2.0),
                   delays_s=(0.0, 0.005, 0.01, 0.02), tolerance: float = 0.05, smooth_s: float = 0.1,
                   level: str = "D", effects=FAULT_PLANT_EFFECTS, sweep: bool = True, progress=None) -> FaultAnalysis:
    """The fault report's numbers: every fault scenario, the margins, the sweep.

    ``progress`` (a :class:`thsa_control.progress.Progress` or None) gets one line per case and phase.
    """
    def step(k, n, text):
        if progress is not None:
            progress.step(k, n, text)

    def phase(text):
        if progress is not None:
            progress.phase(text)

    settings = monitors or MonitorSettings()
    phase("building the fault plant's simulators")
    fine = _simulator(params, level, effects, None)
    coarse = _simulator(params, level, effects, 1e-3)
    scen = fault_scenarios()
    cases = []
    for k, s in enumerate(scen, 1):
        step(k, len(scen), f"{s.name} [{CASE_LABELS['fault']}]")
        cases.append(analyse_fault_case(s, design, params, sim=fine, monitors=settings, tolerance=tolerance,
                                        smooth_s=smooth_s, label=CASE_LABELS["fault"]))
    cases = tuple(cases)
    phase("false-alarm margins on the normal scenarios")
    margins = false_alarm_margins(design, params, monitors=settings, sim=coarse)
    normal_res = max(abs(energy_residual(fine.run(replace(s, monitors=settings), design, params)))
                     for s in normal_scenarios()[:1])
    phase("channel failures on the rigid drive train")
    rigid = _simulator(params, level, RIGID_EFFECTS, None)
    rigid_cases = []
    channel = [s for s in scen if any(f.kind == "channel_failure" for f in s.faults)]
    for k, s in enumerate(channel, 1):
        step(k, len(channel), f"{s.name} [{CASE_LABELS['rigid']}, and the papers' 15 ms]")
        # no limit cycle on the rigid drive train: the recovery needs no averaging
        rigid_cases.append(analyse_fault_case(s, design, params, sim=rigid, monitors=settings, tolerance=tolerance,
                                              smooth_s=0.0, label=CASE_LABELS["rigid"]))
        t_f = min(f.time for f in s.faults)
        # the papers' comparison: the standby enabled by the scenario 15 ms after the fault, the monitors only
        # watch (reconfigure=False), so their 'standby active' flag stays low: the take-over is the schedule's
        papers = replace(s, name=f"{s.name}_papers_15ms", standby_enable=((0.0, 0.0), (t_f + 0.015, 1.0)))
        rigid_cases.append(analyse_fault_case(papers, design, params, sim=rigid, tolerance=tolerance, smooth_s=0.0,
                                              monitors=replace(settings, reconfigure=False),
                                              label=CASE_LABELS["papers"]))
    if sweep:
        phase(f"sweep: {len(scales)} threshold scales x {len(delays_s)} take-over delays")
    points = sweep_monitors(design, params, scales=scales, delays_s=delays_s, monitors=settings, sim=coarse,
                            tolerance=tolerance, smooth_s=smooth_s,
                            rigid_sim=_simulator(params, level, RIGID_EFFECTS, 1e-3)) if sweep else ()
    return FaultAnalysis(level, tuple(coarse.plant.effects), settings, cases, margins, points, normal_res, tolerance,
                         smooth_s, tuple(rigid_cases))
