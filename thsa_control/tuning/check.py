"""`thsa check`: the validation suite in closed-loop nonlinear simulation, against a design's requirements.

For every level and temperature: each run of the suite
(:data:`~.validation.VALIDATION_SUITE`) on the compiled simulator (sampled
every control period, so the current rate is the controller's), its metrics
checked against the design's ``[validation]`` limits (or
:data:`~.validation.DEFAULT_VALIDATION_REQUIREMENTS` where the design has
none), and the velocity-loop margins of ``[requirements.velocity_loop]``
(phase, gain margin, Ms) from the exact loop analysis at that level and
temperature.  A failure names the level, temperature, run and plateau or
operating point.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import tomli_w

from ..errors import DesignError
from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
from ..loops.design import Design, parse_design
from ..model.params import ParameterSet
from .robust import ROBUST_REQUIREMENTS, exact_margins
from .validation import DEFAULT_VALIDATION_REQUIREMENTS, VALIDATION_SUITE, get_validation_scenario, run_metrics

__all__ = ["CheckRow", "CheckReport", "check_design", "validation_limits", "PROVENANCE_MARKER", "write_design",
           "suite_metrics"]

#: Written as ``[tuning].written_by`` into every design ``thsa tune`` writes; ``--out`` may only replace such files.
PROVENANCE_MARKER = "thsa tune (thsa_control.tuning)"

_METRIC_OF = {
    "max_speed_error_percent": ("speed_error_percent", "%"),
    "max_overshoot_percent": ("overshoot_percent", "%"),
    "max_settling_time_s": ("settling_time_s", "s"),
    "max_current_peak_A": ("current_peak_A", "A"),
    "max_current_rate_A_per_s": ("current_rate_peak_A_per_s", "A/s"),
}


def validation_limits(design: Design) -> dict[str, tuple[float, str]]:
    """Limit and origin (``design`` or ``default``) of every validation requirement checked."""
    out = {k: (v, "default") for k, v in DEFAULT_VALIDATION_REQUIREMENTS.items()}
    out["max_current_peak_A"] = (design.current_limit, "default: the clamp")
    out.update({k: (float(v), "design") for k, v in design.validation.items()})
    return out


@dataclass(frozen=True)
class CheckRow:
    """One checked quantity at one level and temperature."""

    level: str
    temperature: float
    item: str
    value: float
    limit: float
    unit: str
    passed: bool
    where: str

    def text(self) -> str:
        """One table line."""
        v = "never" if math.isinf(self.value) else f"{self.value:.4g}"
        return (f"{'PASS' if self.passed else 'FAIL'}  {self.level}  {self.temperature:6.1f}  {self.item:42s} "
                f"{v:>10s} {self.unit:4s} limit {self.limit:g}  {self.where}")


@dataclass(frozen=True)
class CheckReport:
    """Rows of the check, the metrics by (level, temperature, run) and margins by (level, temperature)."""

    design: Design
    rows: tuple[CheckRow, ...]
    metrics: dict
    margins: dict

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.rows)

    @property
    def failures(self) -> tuple[CheckRow, ...]:
        return tuple(r for r in self.rows if not r.passed)

    def text(self) -> str:
        """The pass/fail table and a verdict naming the failing points."""
        head = f"{'':4s}  lvl  degC    {'item':42s} {'value':>10s}"
        lines = [head] + [r.text() for r in self.rows]
        if self.passed:
            lines.append(f"check: PASS ({len(self.rows)} checks)")
        else:
            lines.append(f"check: FAIL ({len(self.failures)} of {len(self.rows)} checks)")
            for r in self.failures:
                lines.append(f"  failing point: level {r.level}, {r.temperature:g} degC, {r.item} = "
                             f"{'never settles' if math.isinf(r.value) else f'{r.value:.4g} {r.unit}'} "
                             f"(limit {r.limit:g}) {r.where}")
        return "\n".join(lines)


def suite_metrics(design: Design, params: ParameterSet, level: str, temperature: float, *,
                  scenarios=VALIDATION_SUITE, effects=DEFAULT_ANALYSIS_EFFECTS) -> dict:
    """Metrics of every run of the suite at one level and temperature (compiled simulator)."""
    from ..model import build_plant
    from ..sim.simulate import SimulationSettings, Simulator

    sim = Simulator(build_plant(level, effects, params=params), SimulationSettings(output_period=None))
    out = {}
    for name in scenarios:
        sc = get_validation_scenario(name).with_temperature(temperature)
        out[name] = run_metrics(sim.run(sc, design, params))
    return out


def check_design(design: Design, params: ParameterSet, *, levels=("A", "B", "C", "D"),
                 temperatures=(-55.0, -30.0, 25.0, 70.0), scenarios=VALIDATION_SUITE,
                 effects=DEFAULT_ANALYSIS_EFFECTS, progress=None) -> CheckReport:
    """Run the validation suite and the margin check at every level and temperature."""
    limits = validation_limits(design)
    margin_req = {k: v for k, v in design.requirements.get("velocity_loop", {}).items() if k in ROBUST_REQUIREMENTS}
    rows, metrics, margins = [], {}, {}
    for level in levels:
        for T in temperatures:
            if progress:
                progress(f"check: level {level}, {T:g} degC ...")
            ms = suite_metrics(design, params, level, T, scenarios=scenarios, effects=effects)
            for name, m in ms.items():
                metrics[(level, T, name)] = m
                for key, (limit, origin) in limits.items():
                    attr, unit = _METRIC_OF[key]
                    value = getattr(m, attr)
                    where = f"[{name}: {m.worst_plateau}]" if attr == "speed_error_percent" else f"[{name}]"
                    rows.append(CheckRow(level, T, f"{name}: {attr} ({origin})", value, limit, unit,
                                         bool(value <= limit), where))
            if margin_req:
                mg = exact_margins(design, params, [T], level=level, effects=effects, requirements=margin_req)[0]
                margins[(level, T)] = mg
                checks = {"min_phase_margin_deg": (mg.phase_margin_deg, "deg", mg.phase_margin_at, ">="),
                          "min_gain_margin_db": (mg.gain_margin_db, "dB", mg.gain_margin_at, ">="),
                          "max_sensitivity_peak": (mg.ms, "-", mg.ms_at, "<=")}
                for key, limit in margin_req.items():
                    value, unit, at, op = checks[key]
                    ok = (value >= limit) if op == ">=" else (value <= limit)
                    ok = bool(ok) and mg.stable
                    rows.append(CheckRow(level, T, f"velocity loop {key.split('_', 1)[1]}", value, float(limit), unit,
                                         ok, f"[worst at {at}]" + ("" if mg.stable else " [closed loop unstable]")))
    return CheckReport(design, tuple(rows), metrics, margins)


def write_design(design: Design, path: str | Path, *, force_marker: str = PROVENANCE_MARKER) -> Path:
    """Write ``design`` as TOML to ``path`` (atomically).

    Refuses (DesignError) to replace an existing file that ``thsa tune`` did
    not write: one whose ``[tuning].written_by`` is not the marker.
    """
    path = Path(path)
    if path.exists():
        try:
            doc = tomllib.loads(path.read_text(encoding="utf-8"))
        except (OSError, tomllib.TOMLDecodeError):
            doc = {}
        if doc.get("tuning", {}).get("written_by") != force_marker:
            raise DesignError(str(path), "exists and was not written by 'thsa tune' (no [tuning] provenance "
                                         "marker): refusing to overwrite it; choose another --out")
    doc = design.to_toml_dict()
    text = tomli_w.dumps(doc)
    parse_design(tomllib.loads(text), source=str(path))  # what we write must load back
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path
