"""The ``Effect`` contract and the effect registry: the one place where the model is extended.

An :class:`Effect` carries everything the workbench knows about a physical
effect, so that no other module names it:

* what it adds: its states, the parameters it reads, the effects it requires
  or supersedes, and ``apply(assembly)`` that adds its terms (torques,
  friction channels, rates, losses, stored energy, outputs) to the structure;
* its **outputs with their neutral values** (:class:`Output`): every effect
  set has the same output signals, those of absent effects at the value they
  have without the effect (the structure writes them from here);
* its **place in the order** (:class:`Phase`): effects are applied by phase,
  then in registration order, because some read what others decide (the axial
  force, the drive-train coupling, the pawl gates);
* its **tracer candidate spec** (:class:`CandidateSpec`: free parameters,
  seeds, window, channel, profiled parameters) or an explicit
  :class:`NotCandidate` with the reason;
* its **neutral parameter values** (at which it adds nothing) or why it has none;
* its **linearisation hints** (:class:`LinearHints`): states that drift in a
  steady motion, states re-expressed relative to another, validity guards,
  the state that probes the main body's inertia, operating-point guesses.

:func:`register` adds an effect to :data:`EFFECTS`; simulation,
linearisation, identification and the tracer then offer it with no other file
touched.  :func:`unregister` removes it again (tests).

This module imports the standard library only; it must not import the effect
modules, the structure or anything outside ``model/``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

__all__ = [
    "Phase", "Output", "CandidateSpec", "NotCandidate", "NoNeutral", "Guard", "OperatingContext", "LinearHints", "Effect",
    "EFFECTS", "EFFECT_ORDER", "register", "unregister", "effect_order", "registered",
]


class Phase(IntEnum):
    """Where an effect is applied; effects of one phase are applied in registration order.

    ``BODIES``: adds a motor-side body or a state that later phases read (a
    second motor, the compliant drive train's coupling).  ``LOAD_PATH``: the
    load path (the surface as a body; it sets the axial force on the nut).
    ``DRIVE``: torques, friction and forces on the drive (may change the axial
    force: read by the no-back).
    ``PAWLS``: gates the no-back pawls.  ``NOBACK``: the no-back, which reads the
    axial force and the pawl gates.  ``STRUCTURE_FAULTS``: faults of the load
    path, the surface and the travel stops (read the load-path force and the
    surface's outputs).  ``DRIVE_FAULTS``: faults of the drive train and the
    motors (read the final coupling and the rotor body).
    """

    BODIES = 10
    LOAD_PATH = 15
    DRIVE = 20
    PAWLS = 30
    NOBACK = 40
    STRUCTURE_FAULTS = 50
    DRIVE_FAULTS = 60


@dataclass(frozen=True)
class Output:
    """An output signal of an effect and its value when the effect is absent.

    ``neutral`` is a number, or ``fn(assembly)`` returning a casadi expression
    or a function of the friction resolution (``fn(res) -> expr``), evaluated
    on the structure's assembly (e.g. the surface position is the nut
    position when the load path is rigid).
    """

    name: str
    unit: str
    neutral: object = 0.0


@dataclass(frozen=True)
class CandidateSpec:
    """How one candidate effect is added and fitted by the tracer.

    ``free``: its parameters identified with the declared ones; ``seeds``:
    starting values where the parameter file has the effect off (0);
    ``window``: where it acts (``moving``, ``all``, ``loaded``, ``reversal``,
    ``clearance``, ``cold``, ``resolved_cogging``, ``load_change``); ``channel``: the channel where it shows most; ``profile``:
    parameters that act through a switch (no gradient), searched over a range
    ``(lo, hi)`` by :func:`~thsa_control.fit.profile.profile_identify` (the
    first finely, the others where they matter) while ``free`` is fitted at
    each value.
    """

    name: str
    free: tuple[str, ...]
    seeds: Mapping[str, float] = field(default_factory=dict)
    window: str = "moving"
    channel: str = "motor_speed"
    profile: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    #: further profiled parameters the model uses as a fraction of the first one (name -> that one's name): the
    #: runs see their product, which is screened first and held while the first is screened
    #: (:func:`~thsa_control.fit.profile.profile_identify`, ``fractions``)
    profile_fractions: Mapping[str, str] = field(default_factory=dict)
    #: a constant-torque explainer: besides being a candidate it may stand for the base mismatch every real
    #: drive has (a drag, an efficiency, a fixture force), fitted in the tracer's base-correction step within
    #: the plausible magnitude (``trace.candidates.PLAUSIBLE``) named here for each free parameter
    base_correction: bool = False
    #: free parameter -> plausibility rule of ``trace.candidates.PLAUSIBLE``: the largest magnitude a healthy rig
    #: can have (a base correction is bounded by it; a found periodic torque larger than it is implausible)
    plausible: Mapping[str, str] = field(default_factory=dict)
    #: rule of ``trace.candidates.STARTS`` giving starting values read off the runs (a static screen), for
    #: parameters whose right value a fit started at the file's cannot reach (a soft zone vs a preload)
    start: str | None = None
    #: parameters freed in a second fit only when the first fit determines every parameter of ``free`` (a mode's
    #: damping once the run resolves its stiffness): freed from the start, a damping stands in for any lag of
    #: the current-to-speed response on a drive train the run shows rigid.  Judged by the same rule (held at the
    #: file value where the second fit does not determine it)
    second_stage: tuple[str, ...] = ()
    #: second-stage parameters whose end of range is a physical value, not a failed estimate (a no-back without a
    #: disk-spring preload: 0 N); the others at a bound are held (a load share of 0 or 1)
    second_stage_range_ends: tuple[str, ...] = ()
    #: second-stage parameters that, moved far from the file's value (``trace.scoring.RESEED_MOVE``), have the joint
    #: fit started again with the first stage's parameters at their file values: those were fitted around the file's
    #: value and carry its error into the start (a no-back's coefficients fitted at the file's preload)
    second_stage_reseed: tuple[str, ...] = ()
    #: declared parameters this effect's law reads as their value at its reference condition, i.e. outside its
    #: window (``temperature_friction`` reads ``gear.viscous_friction`` as the 25 degC drag ``b_25``).  Runs with
    #: (almost) no moving sample outside the window do not determine them: fitted there, they take this effect's
    #: share (a cold run's drag fitted as a 25 degC viscous friction 9 x the file's); the tracer holds them at
    #: their file values (``trace.candidates.reference_not_determined``)
    reference: tuple[str, ...] = ()
    #: free parameter -> the standard error above which the runs do not determine it, for a parameter whose zero is
    #: not the effect's absence and whose file value is no scale of what matters (a share, 0..1, assumed within
    #: +-0.1): the assumption's spread, which a run that determines it must narrow; default the reference magnitude
    #: (file value, seed or plausible bound; ``trace.scoring.determination``)
    resolution: Mapping[str, float] = field(default_factory=dict)
    #: parameters of ``free`` held, one more at a time in this order, where a fit determines none of them (a null
    #: direction the law has on some runs: a load path whose load never lifts a preloaded contact nor closes a
    #: clearance shows the contacts' summed stiffness, not the clearance or the split): each at its start value
    #: (``start``'s screen, else the file's), the rest refitted until the runs determine one; the usual holding
    #: then goes on from that fit (``trace.scoring._hold_undetermined``).  Empty: such a candidate is refused as
    #: "no parameter determined by the run"
    singular_hold: tuple[str, ...] = ()


@dataclass(frozen=True)
class NotCandidate:
    """An effect the tracer does not offer by default, and why (naming it explicitly still scores it)."""

    reason: str


@dataclass(frozen=True)
class NoNeutral:
    """An effect no parameter value removes exactly (a body of its own, an always-dragged rotor), and why."""

    reason: str


@dataclass(frozen=True)
class Guard:
    """A validity guard of linear models: a point is invalid within ``band`` of an edge.

    ``distance(x, p)`` is the distance from the edge (casadi; ``x`` maps the
    linearised model's state names to symbols, ``p`` the parameter names);
    ``band`` names the field of the linearisation settings that gives the band.
    """

    name: str
    distance: Callable[[Mapping, Mapping], object]
    band: str


@dataclass(frozen=True)
class OperatingContext:
    """What an effect's operating-point hint may read (a steady motion at one condition).

    ``speed`` [rad/s, motor shaft], ``nut_speed`` [m/s], ``load_force`` [N],
    ``current`` the guessed active-motor current [A], ``torque_constant``
    [N m/A], ``values`` the parameter values by name, ``pawl`` the placement
    of the engaged pawl (``"inside"`` or ``"edge"``), ``rest_state()`` the
    plant's state at rest under ``load_force`` (state name -> value; computed on call).
    """

    speed: float
    nut_speed: float
    load_force: float
    current: float
    torque_constant: float
    values: Mapping[str, float]
    pawl: str
    rest_state: Callable[[], Mapping[str, float]]


@dataclass(frozen=True)
class LinearHints:
    """What linearisation needs to know about an effect.

    ``drifting``: states that ramp in a steady motion and are excluded from
    the linear models.  ``relative``: ``state -> (new_name, reference)``, the
    state is re-expressed as ``reference - state`` (so that a steady motion,
    in which both ramp, is an equilibrium).  ``guards``: validity guards.
    ``inertia_probe``: ``(state, gain(p))``: the main body's ``1/J`` is
    ``d(d motor_speed/dt)/d(state) / gain`` (the effect that sets the torque
    entering the main body; the structure's is the motor current and ``Kt``).
    ``operating_point(ctx) -> (held, guesses)``: states held at a value and
    initial guesses of the solved ones (:class:`OperatingContext`).
    ``at_reversal(values) -> held``: its states at a reversal of motion
    (friction maps, describing functions).  ``kinks``: ``signal -> meaning``
    of a kink the smoothness check may find in one of its signals.
    """

    drifting: tuple[str, ...] = ()
    relative: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    guards: tuple[Guard, ...] = ()
    inertia_probe: tuple[str, Callable[[Mapping], object]] | None = None
    operating_point: Callable[[OperatingContext], tuple[dict, dict]] | None = None
    at_reversal: Callable[[Mapping], dict] | None = None
    kinks: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Effect:
    """A physical effect: what it adds, the function that adds it, and what the tools need to know.

    Parameters
    ----------
    name : str
        Effect name used in effect sets.
    summary : str
        One line for listings.
    states : tuple of StateInfo
        States it adds.
    parameters : tuple of str
        Parameters it reads (beyond the structure's).
    requires : tuple of str
        Effects that must be in the same set.
    apply : callable
        ``apply(assembly)`` adds the terms.
    supersedes : tuple of str
        Effects it replaces when both are asked for (the detailed no-back
        replaces level A's ideal one).
    phase : Phase
        Its place in the application order.
    outputs : tuple of Output
        Its output signals with their neutral values.
    candidate : CandidateSpec or NotCandidate
        The tracer's candidate spec, or why it is not a candidate.
    linear : LinearHints
        Linearisation hints.
    neutral : mapping or NoNeutral
        Parameter values at which the effect adds nothing (with healthy fault
        inputs; an empty mapping: at the parameter file's values), or why no
        value does.  The registry suite checks the plant is then the base.
    parameter_defaults : tuple of Parameter
        Parameters the effect brings beyond the embedded parameter file (value,
        unit, bounds, source); :func:`~thsa_control.model.params.default_parameters`
        adds them, so a parameter file may override them like any other.
    """

    name: str
    summary: str
    states: tuple
    parameters: tuple[str, ...]
    requires: tuple[str, ...]
    apply: Callable
    supersedes: tuple[str, ...] = ()
    phase: Phase = Phase.DRIVE
    outputs: tuple[Output, ...] = ()
    candidate: CandidateSpec | NotCandidate | None = None
    linear: LinearHints = field(default_factory=LinearHints)
    neutral: Mapping[str, float] | NoNeutral | None = None
    parameter_defaults: tuple = ()


#: Every registered effect by name, in registration order.
EFFECTS: dict[str, Effect] = {}


def register(effect: Effect, *, replace: bool = False) -> Effect:
    """Add ``effect`` to the registry (returns it, so a module may write ``X = register(Effect(...))``).

    Raises
    ------
    ValueError
        A name already registered (unless ``replace``), a phase that is not a
        :class:`Phase`, no tracer candidate spec nor a reason it is not one
        (an effect is never left out of the tracer silently), a candidate spec
        named for another effect, or no neutral values nor a reason it has none.
    """
    if not replace and effect.name in EFFECTS:
        raise ValueError(f"effect {effect.name!r} is already registered")
    if not isinstance(effect.phase, Phase):
        raise ValueError(f"effect {effect.name!r}: phase {effect.phase!r} is not a Phase")
    if not isinstance(effect.candidate, (CandidateSpec, NotCandidate)):
        raise ValueError(f"effect {effect.name!r}: declare its tracer candidate spec (CandidateSpec) or why it is "
                         f"not a candidate (NotCandidate)")
    if isinstance(effect.candidate, CandidateSpec) and effect.candidate.name != effect.name:
        raise ValueError(f"effect {effect.name!r}: its candidate spec is named {effect.candidate.name!r}")
    if not isinstance(effect.neutral, (Mapping, NoNeutral)):
        raise ValueError(f"effect {effect.name!r}: declare the parameter values at which it adds nothing "
                         f"(neutral) or why there are none (NoNeutral)")
    EFFECTS[effect.name] = effect
    return effect


def unregister(name: str) -> Effect:
    """Remove effect ``name`` from the registry and return it (KeyError if unknown)."""
    return EFFECTS.pop(name)


def effect_order() -> tuple[str, ...]:
    """Names of the registered effects in application order (phase, then registration)."""
    rank = {n: k for k, n in enumerate(EFFECTS)}
    return tuple(sorted(EFFECTS, key=lambda n: (int(EFFECTS[n].phase), rank[n])))


def registered() -> tuple[Effect, ...]:
    """The registered effects in registration order."""
    return tuple(EFFECTS.values())


class _Order(Sequence):
    """Live view of :func:`effect_order` (a registered effect appears in it at once)."""

    def __getitem__(self, k):
        return effect_order()[k]

    def __len__(self) -> int:
        return len(EFFECTS)

    def __iter__(self) -> Iterator[str]:
        return iter(effect_order())

    def __contains__(self, name) -> bool:
        return name in EFFECTS

    def __eq__(self, other) -> bool:
        return tuple(self) == tuple(other) if isinstance(other, (tuple, list, _Order)) else NotImplemented

    def __hash__(self):  # pragma: no cover - a view is not a key
        raise TypeError("EFFECT_ORDER is a live view")

    def __add__(self, other):
        return tuple(self) + tuple(other)

    def __repr__(self) -> str:
        return repr(effect_order())


#: Application order of the registered effects (a live view of :func:`effect_order`).
EFFECT_ORDER: Sequence[str] = _Order()
