"""Physical effects that extend a base model without touching it.

A model is a base rheological element plus effects (``Model(three_element(...),
(RelaxationBranch(...),))``), much as PySINDy assembles a library from parts. An
effect changes one stage of the chain material -> mechanics -> measurement through
a hook, so the base elements and the FE model never learn about it:

- ``material(element)``: a structural change of the rheology (an extra arm);
- ``stress_scale(strain)``: a factor on the specimen's stress that depends on its
  nominal strain (a nonlinear elastic response);
- ``voigt_spring(strain)``: the base's Voigt spring made nonlinear (its stress per
  unit E at its own nominal strain); the response is then integrated numerically
  (``response.respond_voigt_spring``), and the FE simulator, linear, does not take it;
- ``measured_force(t, force, release)``: what reaches the sensor besides the
  specimen's stress (adhesion, drift), given when the stage let go (``Release``);
- ``measured_markers(t, displacement)``: what the camera sees of the markers'
  displacements (a camera's drift, scale or distortion).

``stress_scale``, ``measured_force`` and ``measured_markers`` get samples in time order (``t`` increasing)
and return one row per sample. An effect without memory (``memory`` 0, the default)
must give each row from that sample alone: the streaming simulator then calls it
with the current sample only. An effect whose reading or stress depends on its past
(a sensor's lag, hysteresis, damage) says how far back in ``memory`` (seconds,
``math.inf``: the whole history); a row may then depend on the rows before it, and
the streaming simulator calls the hooks with that stretch of its history (its cost
per sample grows with it), the fit with the whole record.

An effect is a family of forms (a drift that is a line or that settles; one
relaxation arm or two): every form of a family shares its ``id`` and says which it is
in ``form``; the first registered is the family's default. The diagnosis fits the
default and, where the data ask for the family, its other forms, and names the
family with the form that fits best.

A user registers an effect (or another form of one) from their own package with
``@register_effect`` or through the ``rheo_ros.effects`` entry-point group; effect rates (a relaxation
time) are parameters to fit, not a list to enumerate. For the model-discovery loop
(``rheo_ros.diagnosis``) an effect also says where its fit may start (``starts``),
which phases show it (``shows_in``), which of its parameters may take either sign
(``signed``; the rest are positive), what experiment would pin it down
(``resolving_experiment``) and its own time constants (``times``: two effects of
separate causes rarely share one, ``diagnosis.decision.shared_times``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from importlib.metadata import entry_points
from typing import ClassVar, TypeVar

import numpy as np

from rheo_ros.experiment import StageProfile
from rheo_ros.models.elements import Element, Parallel, maxwell


@dataclass(frozen=True)
class Release:
    """The moment the stage lost contact: time (s) and each node's force then (N)."""

    t: float
    force: np.ndarray

    @classmethod
    def find(cls, t: np.ndarray, force: np.ndarray, contact: np.ndarray) -> Release | None:
        """First loss of contact in a sampled history (force taken at the last contact sample)."""
        contact = np.asarray(contact, bool)
        lost = np.flatnonzero(contact[:-1] & ~contact[1:])
        return None if lost.size == 0 else cls(float(t[lost[0] + 1]), np.asarray(force[lost[0]]))


@dataclass(frozen=True)
class FitContext:
    """What an effect's starting guesses may use (``Effect.starts``).

    Attributes:
        profile: the record's stage profile (phase times, depth).
        params: the current model's fitted parameters (``E``, ``c1``, ``c2``, ``gamma``, ...).
        peak_force: the largest force one tactile segment read (N).
        force_t: (T,) s; residual: (T, nodes) N, measured minus the current model;
        live: (T, nodes) the readings that count (above the dead band).
        cells: (nodes,) tactile cells per segment (a uniform pressure's force is in
            proportion), None where not known.
    """

    profile: StageProfile
    params: Mapping[str, float]
    peak_force: float
    force_t: np.ndarray
    residual: np.ndarray
    live: np.ndarray
    cells: np.ndarray | None = None

    @property
    def cell_shares(self) -> tuple[float, ...] | None:
        """Each segment's cells over the mean (what a uniform pressure gives each segment
        of an average segment's force); None where not known."""
        return None if self.cells is None else tuple((self.cells / np.mean(self.cells)).tolist())


def segment_shares(shares: tuple[float, ...] | None, nodes: int) -> np.ndarray:
    """``FitContext.cell_shares`` as an array over ``nodes`` segments (equal where None)."""
    return np.ones(nodes) if shares is None else np.asarray(shares)


class Effect:
    """Base of all effects: a frozen dataclass whose float fields are its parameters.

    Class attributes a subclass sets:
        id: the effect's (its family's) name in models and reports.
        form: which of the family's forms it is (the first registered is the default).
        shows_in: phases whose residuals it changes most (``before``, ``pull``,
            ``keep``, ``release``): the diagnosis checks that adding it moved them.
        signed: parameters that may take either sign (fitted on a linear scale; the
            rest are positive and fitted on a log scale).
        signals: which readings it changes, ``force`` and/or ``markers``: the diagnosis
            judges it on their misfit.
        resolving_experiment: what to record when the data cannot decide on it.
    """

    id: ClassVar[str]
    form: ClassVar[str] = "default"
    shows_in: ClassVar[tuple[str, ...]] = ()
    signed: ClassVar[tuple[str, ...]] = ()
    signals: ClassVar[tuple[str, ...]] = ("force",)
    resolving_experiment: ClassVar[str] = "a longer record"

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        """Where a fit of this effect may start; the fit tries each and keeps the best.
        Default: the class's field defaults (a user effect without them overrides this)."""
        try:
            return (cls(),)
        except TypeError:
            raise TypeError(f"effect {cls.id!r}: give its fields defaults or override starts()") from None

    def describe(self) -> str:
        """The fitted effect in words, for the diagnosis's evidence."""
        return ", ".join(f"{k.split('.', 1)[1]} {v:.3g}" for k, v in self.parameters.items())

    @property
    def parameters(self) -> dict[str, float]:
        # A field with metadata {"parameter": False} is set up, not fitted (a layout).
        return {f"{self.id}.{f.name}": float(getattr(self, f.name)) for f in fields(self)
                if f.metadata.get("parameter", True)}

    def with_parameters(self, values: Mapping[str, float]) -> Effect:
        own = {k.split(".", 1)[1]: v for k, v in values.items() if k.startswith(self.id + ".")}
        return replace(self, **own)

    def material(self, element: Element) -> Element:
        return element

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        """Factor on the stress at nominal compressive strain ``strain`` (depth / height)."""
        return np.ones_like(strain)

    def voigt_spring(self, strain: np.ndarray) -> np.ndarray:
        """The Voigt spring's stress per unit E at its nominal strain (linear: the strain)."""
        return strain

    @property
    def nonlinear_spring(self) -> bool:
        """Whether this effect makes the Voigt spring nonlinear (overrides ``voigt_spring``)."""
        return type(self).voigt_spring is not Effect.voigt_spring

    @property
    def moves_markers(self) -> bool:
        """Whether this effect changes what the camera sees (overrides ``measured_markers``)."""
        return type(self).measured_markers is not Effect.measured_markers

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        """``force``: (T, nodes) in N at times ``t`` (s) -> the nodal forces the sensor
        feels; ``release``: when the stage let go (None: not yet)."""
        return force

    def measured_markers(self, t: np.ndarray, displacement: np.ndarray) -> np.ndarray:
        """``displacement``: (T, N, 2) in m of the markers at times ``t`` (s) -> what the
        camera sees of them."""
        return displacement

    @property
    def memory(self) -> float:
        """Seconds of past samples a row of ``stress_scale``, ``measured_force`` or
        ``measured_markers`` depends on (0: none; ``math.inf``: all of them)."""
        return 0.0

    @property
    def times(self) -> dict[str, float]:
        """The effect's own time constants (s) by what they are ("relaxation time"):
        the decisions compare them across effects (``diagnosis.decision.shared_times``).
        Default: none."""
        return {}


_REGISTRY: dict[str, dict[str, type[Effect]]] = {}   # id -> form -> class, the default first
E = TypeVar("E", bound=type[Effect])


def register_effect(cls: E) -> E:
    """Class decorator: make an effect available by its ``id`` (a further form of a
    family already registered when its ``form`` is new)."""
    forms = _REGISTRY.setdefault(cls.id, {})
    if forms.get(cls.form, cls) is not cls:
        raise ValueError(f"effect id {cls.id!r} form {cls.form!r} is registered already")
    forms[cls.form] = cls
    return cls


def unregister_effect(effect_id: str) -> None:
    """Forget a registered effect, every form (a plugin unloaded, a test's own effect)."""
    _REGISTRY.pop(effect_id, None)


def catalogue() -> tuple[str, ...]:
    """The effect ids known now: the package's, those registered with
    ``@register_effect`` and those of the ``rheo_ros.effects`` entry-point group."""
    for ep in entry_points(group="rheo_ros.effects"):
        effect_class(ep.name)
    return tuple(_REGISTRY)


def effect_forms(effect_id: str) -> tuple[type[Effect], ...]:
    """Every form of the effect ``effect_id``, its default first (own catalogue, then
    entry points)."""
    if effect_id not in _REGISTRY:
        for ep in entry_points(group="rheo_ros.effects"):
            if ep.name == effect_id:
                register_effect(ep.load())
    try:
        return tuple(_REGISTRY[effect_id].values())
    except KeyError:
        raise KeyError(f"unknown effect {effect_id!r}; known: {', '.join(sorted(_REGISTRY))}") from None


def effect_class(effect_id: str, form: str | None = None) -> type[Effect]:
    """The effect registered under ``effect_id``: its ``form``, or its default form."""
    forms = effect_forms(effect_id)
    if form is None:
        return forms[0]
    for cls in forms:
        if cls.form == form:
            return cls
    raise KeyError(f"effect {effect_id!r} has no form {form!r}; its forms: {', '.join(c.form for c in forms)}")


@register_effect
@dataclass(frozen=True)
class RelaxationBranch(Effect):
    """A second relaxation mode: a Maxwell arm (stiffness Pa, viscosity Pa s) in parallel.

    Shows in the keep phase as a fast early drop before the slow tail (eq. 22).
    """

    id: ClassVar[str] = "relaxation_branch"
    form: ClassVar[str] = "one_arm"
    shows_in: ClassVar[tuple[str, ...]] = ("keep",)
    resolving_experiment: ClassVar[str] = "a keep at least five times the fast relaxation time, sampled well within it"
    stiffness: float
    viscosity: float

    @property
    def time(self) -> float:
        """The arm's relaxation time (s)."""
        return self.viscosity / self.stiffness

    @property
    def times(self) -> dict[str, float]:
        return {"relaxation time": self.time}

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        # A fast mode within the keep: a time a twentieth and a quarter of it.
        k = 0.5 * context.params.get("E", 1.0)
        return tuple(cls(k, k * context.profile.keep_time * f) for f in (0.05, 0.25))

    def describe(self) -> str:
        return (f"a Maxwell arm of {self.stiffness:.3g} Pa and {self.viscosity:.3g} Pa s "
                f"(relaxation time {self.time:.3g} s)")

    def material(self, element: Element) -> Element:
        arm = maxwell(self.stiffness, self.viscosity, (f"{self.id}.stiffness", f"{self.id}.viscosity"))
        return Parallel((element, arm))


@register_effect
@dataclass(frozen=True)
class SensorDrift(Effect):
    """Tactile offset (N per node) and linear drift (N/s per node) from t = 0."""

    id: ClassVar[str] = "sensor_drift"
    form: ClassVar[str] = "linear"
    # Every live reading carries it; before contact and after release it is alone, but an
    # offset below the dead band shows only where the specimen presses (in pull and keep).
    shows_in: ClassVar[tuple[str, ...]] = ("before", "pull", "keep", "release")
    signed: ClassVar[tuple[str, ...]] = ("offset", "rate")
    resolving_experiment: ClassVar[str] = "a longer record before contact and after release"
    offset: float
    rate: float

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        guess = cls(0.01 * context.peak_force, 1e-4 * context.peak_force / max(context.profile.t_end, 1.0))
        # The line through the residual where nothing presses (before contact, after release).
        t, prof = context.force_t, context.profile
        quiet = ((t < prof.t_pull_start) | (t > prof.t_keep_end))[:, None] & context.live
        if quiet.sum() < 10:
            return (guess,)
        tt = np.broadcast_to(t[:, None], quiet.shape)[quiet]
        if np.ptp(tt) <= 0:
            return (guess, cls(float(np.mean(context.residual[quiet])), 0.0))
        rate, offset = np.polyfit(tt, context.residual[quiet], 1)
        return (guess, cls(float(offset), float(rate)))

    def describe(self) -> str:
        return f"a tactile offset of {self.offset:.3g} N per segment drifting by {self.rate:.3g} N/s"

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        return force + (self.offset + self.rate * np.asarray(t))[:, None]


@register_effect
@dataclass(frozen=True)
class Adhesion(Effect):
    """The specimen sticks to the sensor after release: from the moment the stage
    loses contact, each node keeps ``fraction`` of the force it carried as the stage
    let go, fading over ``time`` (s). Shows in the release phase: the force does not
    return to zero."""

    id: ClassVar[str] = "adhesion"
    form: ClassVar[str] = "fading"
    shows_in: ClassVar[tuple[str, ...]] = ("release",)
    resolving_experiment: ClassVar[str] = "a longer record after release"
    fraction: float
    time: float

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        return (cls(0.1, max(context.profile.release_time, 1.0)),)

    def describe(self) -> str:
        return f"{100 * self.fraction:.3g} % of the force held after release, fading over {self.time:.3g} s"

    @property
    def times(self) -> dict[str, float]:
        return {"fading time": self.time}

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        if release is None:
            return force
        since = np.asarray(t) - release.t
        fade = np.where(since >= 0, np.exp(-np.maximum(since, 0.0) / self.time), 0.0)
        return force + self.fraction * fade[:, None] * release.force[None]


@register_effect
@dataclass(frozen=True)
class StrainStiffening(Effect):
    """Stiffness grows with strain: stress x (1 + ``coefficient`` x nominal strain).

    Shows in the pull phase: the force curves up with depth.
    """

    id: ClassVar[str] = "strain_stiffening"
    form: ClassVar[str] = "linear"
    shows_in: ClassVar[tuple[str, ...]] = ("pull",)
    resolving_experiment: ClassVar[str] = "a deeper push"
    coefficient: float

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        return (cls(1.0),)

    def describe(self) -> str:
        return f"stress x (1 + {self.coefficient:.3g} x strain)"

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        return 1.0 + self.coefficient * np.maximum(strain, 0.0)


@register_effect
@dataclass(frozen=True)
class TwoRelaxationArms(RelaxationBranch):
    """Two relaxation modes: Maxwell arms (stiffness Pa, viscosity Pa s) ``stiffness``,
    ``viscosity`` and ``stiffness_2``, ``viscosity_2`` in parallel with the base."""

    form: ClassVar[str] = "two_arms"
    stiffness_2: float = 1.0
    viscosity_2: float = 1.0

    @property
    def time_2(self) -> float:
        return self.viscosity_2 / self.stiffness_2

    @property
    def times(self) -> dict[str, float]:
        return {"first relaxation time": self.time, "second relaxation time": self.time_2}

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        # A fast and a slower mode within the keep: a fortieth and a fifth of it.
        k = 0.25 * context.params.get("E", 1.0)
        keep = context.profile.keep_time
        return (cls(k, k * keep * 0.025, k, k * keep * 0.2),)

    def describe(self) -> str:
        return (f"two Maxwell arms: {self.stiffness:.3g} Pa, relaxation time {self.time:.3g} s, and "
                f"{self.stiffness_2:.3g} Pa, {self.time_2:.3g} s")

    def material(self, element: Element) -> Element:
        second = maxwell(self.stiffness_2, self.viscosity_2, (f"{self.id}.stiffness_2", f"{self.id}.viscosity_2"))
        return Parallel((super().material(element), second))


# The settling times, as shares of the record, the settling drifts start from: an effect
# found first can take up the quiet readings' share of the drift (a held adhesion the
# level after release), so a start read off them alone settles nowhere (generator seed
# 17 bag 14: a constant offset, where from 0.2 of the record the fit found the truth).
SETTLING_GRID = (0.03, 0.1, 0.3, 1.0)


@register_effect
@dataclass(frozen=True)
class SettlingDrift(Effect):
    """Each tactile cell's baseline settles exponentially from t = 0: ``offset +
    amplitude (1 - exp(-t / time))`` (N per average segment), each segment's share in
    proportion to its cells (``shares``: cells over the mean; equal when not known)."""

    id: ClassVar[str] = "sensor_drift"
    form: ClassVar[str] = "settling"
    shows_in: ClassVar[tuple[str, ...]] = SensorDrift.shows_in
    signed: ClassVar[tuple[str, ...]] = ("offset", "amplitude")
    resolving_experiment: ClassVar[str] = SensorDrift.resolving_experiment
    offset: float
    amplitude: float
    time: float
    shares: tuple[float, ...] | None = field(default=None, metadata={"parameter": False})

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        return tuple(replace(e, shares=context.cell_shares) for e in cls._starts(context))

    @classmethod
    def _starts(cls, context: FitContext) -> tuple[Effect, ...]:
        # Settled by the end of the record at the level the quiet readings after release
        # show (before contact there is often only a second), over a tenth or a third of it;
        # or the linear form's line through the quiet readings, the same rise over the record.
        t, prof = context.force_t, context.profile
        t_end = max(prof.t_end, 1.0)
        after = (t > prof.t_keep_end)[:, None] & context.live
        level = float(np.mean(context.residual[after])) if after.sum() >= 10 else 0.01 * context.peak_force
        out = [cls(0.0, level, f * t_end) for f in (0.1, 0.3)]
        lines = SensorDrift.starts(context)
        out += [cls(line.offset, line.rate * t_end, 0.3 * t_end) for line in lines[1:]]   # [0]: a blind guess
        # No settling yet, over each time of the grid: the fit's start (``diagnosis.fits``)
        # takes a linearised step from each, which sets the level with the base's values.
        out += [cls(0.0, 0.0, share * t_end) for share in SETTLING_GRID]
        return tuple(out)

    def describe(self) -> str:
        return (f"a tactile offset of {self.offset:.3g} N per segment settling by {self.amplitude:.3g} N "
                f"over {self.time:.3g} s")

    @property
    def times(self) -> dict[str, float]:
        return {"settling time": self.time}

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        settled = -np.expm1(-np.maximum(np.asarray(t), 0.0) / self.time)
        shares = segment_shares(self.shares, np.shape(force)[1])
        return force + (self.offset + self.amplitude * settled)[:, None] * shares[None]


class PerSegmentEffect(Effect):
    """Base of effects with one value per tactile segment: each tuple field named in
    ``per_segment`` (field -> parameter stem) is fitted as ``<stem>_P<j>``, one per
    segment, signed (a baseline may move either way); the other fields are fitted as
    usual (positive unless in ``signed_scalars``). The tuples' length is the layout's:
    ``starts`` builds them from the residual's segments."""

    per_segment: ClassVar[dict[str, str]] = {}
    signed_scalars: ClassVar[tuple[str, ...]] = ()

    @property
    def signed(self) -> tuple[str, ...]:   # type: ignore[override]
        return (*self._segment_names(), *self.signed_scalars)

    def _segment_names(self) -> list[str]:
        return [f"{stem}_P{j + 1}" for name, stem in self.per_segment.items()
                for j in range(len(getattr(self, name)))]

    @property
    def parameters(self) -> dict[str, float]:
        values = [v for name in self.per_segment for v in getattr(self, name)]
        out = {f"{self.id}.{n}": float(v) for n, v in zip(self._segment_names(), values)}
        scalars = {f"{self.id}.{f.name}": float(getattr(self, f.name)) for f in fields(self)
                   if f.name not in self.per_segment and f.metadata.get("parameter", True)}
        return out | scalars

    def with_parameters(self, values: Mapping[str, float]) -> Effect:
        new = {k.split(".", 1)[1]: float(values.get(k, v)) for k, v in self.parameters.items()}
        tuples = {name: tuple(new.pop(f"{stem}_P{j + 1}") for j in range(len(getattr(self, name))))
                  for name, stem in self.per_segment.items()}
        return replace(self, **tuples, **new)


def _quiet_lines(context: FitContext) -> tuple[list[float], list[float]]:
    """Each segment's line (offset N, rate N/s) through its residual where nothing
    presses (before contact, after release); the pooled line (the linear form's start)
    where a segment has too few quiet readings of its own."""
    t, prof = context.force_t, context.profile
    nodes = context.residual.shape[1]
    pooled = SensorDrift.starts(context)[-1]
    quiet = ((t < prof.t_pull_start) | (t > prof.t_keep_end))[:, None] & context.live
    offsets, rates = [pooled.offset] * nodes, [pooled.rate] * nodes
    for j in range(nodes):
        tj = t[quiet[:, j]]
        if tj.size >= 10 and np.ptp(tj) > 0:
            rates[j], offsets[j] = (float(v) for v in np.polyfit(tj, context.residual[quiet[:, j], j], 1))
    return offsets, rates


class _DriftPerSegment(PerSegmentEffect):
    """What the per-segment drift forms share with their family."""

    id: ClassVar[str] = "sensor_drift"
    shows_in: ClassVar[tuple[str, ...]] = SensorDrift.shows_in
    resolving_experiment: ClassVar[str] = SensorDrift.resolving_experiment


@register_effect
@dataclass(frozen=True)
class SegmentDrift(_DriftPerSegment):
    """Each tactile segment's own baseline: ``offsets[j] + rates[j] t`` (N, N/s) on
    segment j from t = 0 (a segment whose cells warm or creep apart from the others).
    Its parameters are ``offset_P<j>`` and ``rate_P<j>``, one pair per segment."""

    form: ClassVar[str] = "per_segment"
    per_segment: ClassVar[dict[str, str]] = {"offsets": "offset", "rates": "rate"}
    offsets: tuple[float, ...] = ()
    rates: tuple[float, ...] = ()

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        offsets, rates = _quiet_lines(context)
        return (cls(tuple(offsets), tuple(rates)),)

    def describe(self) -> str:
        return ("tactile offsets of " + ", ".join(f"{o:.3g}" for o in self.offsets) + " N drifting by "
                + ", ".join(f"{r:.3g}" for r in self.rates) + " N/s (P1, P2, ...)")

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        t = np.asarray(t)[:, None]
        return force + np.asarray(self.offsets)[None] + np.asarray(self.rates)[None] * t


@register_effect
@dataclass(frozen=True)
class SegmentSettlingDrift(_DriftPerSegment):
    """Each tactile segment's baseline settles on its own level over one shared time:
    ``offsets[j] + amplitudes[j] (1 - exp(-t / time))`` (N; cells settling alike but by
    different amounts). Parameters ``offset_P<j>``, ``amplitude_P<j>`` and ``time``."""

    form: ClassVar[str] = "settling_per_segment"
    per_segment: ClassVar[dict[str, str]] = {"offsets": "offset", "amplitudes": "amplitude"}
    offsets: tuple[float, ...] = ()
    amplitudes: tuple[float, ...] = ()
    time: float = 1.0

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        # The settling form's starts with its level shared out by the cells, and each
        # segment's quiet line read as a settling over a third of the record.
        out = []
        for e in SettlingDrift.starts(context):
            shares = np.ones(context.residual.shape[1]) if e.shares is None else np.asarray(e.shares)
            out.append(cls(tuple((e.offset * shares).tolist()), tuple((e.amplitude * shares).tolist()), e.time))
        offsets, rates = _quiet_lines(context)
        span = 0.3 * max(context.profile.t_end, 1.0)
        out.append(cls(tuple(offsets), tuple(r * span for r in rates), span))
        zeros = (0.0,) * context.residual.shape[1]
        out += [cls(zeros, zeros, share * max(context.profile.t_end, 1.0)) for share in SETTLING_GRID]
        return tuple(out)

    def describe(self) -> str:
        return ("tactile offsets of " + ", ".join(f"{o:.3g}" for o in self.offsets) + " N settling by "
                + ", ".join(f"{a:.3g}" for a in self.amplitudes) + f" N (P1, P2, ...) over {self.time:.3g} s")

    @property
    def times(self) -> dict[str, float]:
        return {"settling time": self.time}

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        settled = -np.expm1(-np.maximum(np.asarray(t), 0.0) / self.time)[:, None]
        return force + np.asarray(self.offsets)[None] + np.asarray(self.amplitudes)[None] * settled


@register_effect
@dataclass(frozen=True)
class HeldAdhesion(Effect):
    """The specimen stays stuck after release: each node keeps ``fraction`` of the force
    it carried as the stage let go, for the whole record."""

    id: ClassVar[str] = "adhesion"
    form: ClassVar[str] = "held"
    shows_in: ClassVar[tuple[str, ...]] = Adhesion.shows_in
    resolving_experiment: ClassVar[str] = Adhesion.resolving_experiment
    fraction: float

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        return (cls(0.1),)

    def describe(self) -> str:
        return f"{100 * self.fraction:.3g} % of the force held after release"

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        if release is None:
            return force
        held = (np.asarray(t) >= release.t).astype(float)
        return force + self.fraction * held[:, None] * release.force[None]


@register_effect
@dataclass(frozen=True)
class ExponentialStiffening(StrainStiffening):
    """Stiffness grows exponentially with strain: stress x exp(``coefficient`` x nominal strain)."""

    form: ClassVar[str] = "exponential"

    def describe(self) -> str:
        return f"stress x exp({self.coefficient:.3g} x strain)"

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        return np.exp(self.coefficient * np.maximum(strain, 0.0))


@register_effect
@dataclass(frozen=True)
class PowerLawStiffening(StrainStiffening):
    """The stress grows as a power of strain: stress x (strain / ``REFERENCE``)^``coefficient``,
    a stress ~ strain^(1 + coefficient) (Hertz-like contact, soft tissue: stiffness from
    nothing at first touch). E is the modulus at ``REFERENCE`` strain."""

    form: ClassVar[str] = "power_law"
    REFERENCE: ClassVar[float] = 0.1   # the strain at which E is the secant modulus

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        return (cls(0.5),)

    def describe(self) -> str:
        return f"stress x (strain / {self.REFERENCE:g})^{self.coefficient:.3g}"

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        return (np.maximum(strain, 0.0) / self.REFERENCE) ** self.coefficient


@register_effect
@dataclass(frozen=True)
class VoigtSpringStiffening(StrainStiffening):
    """The Voigt spring alone stiffens: its stress is E (exp(``coefficient`` eps_v) - 1) /
    ``coefficient`` at its own strain eps_v; the dashpots stay linear. Unlike a factor on
    the whole stress, it stiffens what the spring carries: the creep the keep shows and
    the recovery after release, not the viscous share of the pull."""

    form: ClassVar[str] = "voigt_exponential"

    def describe(self) -> str:
        return f"Voigt spring E (exp({self.coefficient:.3g} x strain) - 1) / {self.coefficient:.3g}"

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        return np.ones_like(strain)   # not the linear form's factor: the spring alone stiffens

    def voigt_spring(self, strain: np.ndarray) -> np.ndarray:
        if abs(self.coefficient) < 1e-9:
            return strain * (1.0 + 0.5 * self.coefficient * strain)
        return np.expm1(self.coefficient * strain) / self.coefficient


@dataclass(frozen=True)
class Model:
    """A base element with effects; ``name`` is ``base+effect+...`` as in the JSON report."""

    base: Element
    effects: tuple[Effect, ...] = ()
    base_name: str = "three_element"

    @property
    def name(self) -> str:
        return "+".join([self.base_name, *(e.id for e in self.effects)])

    def rheology(self) -> Element:
        element = self.base
        for effect in self.effects:
            element = effect.material(element)
        return element

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        scale = np.ones_like(np.asarray(strain, dtype=float))
        for effect in self.effects:
            scale = scale * effect.stress_scale(strain)
        return scale

    @property
    def moves_markers(self) -> bool:
        """Whether an effect changes what the camera sees of the elastic shape."""
        return any(e.moves_markers for e in self.effects)

    @property
    def voigt_spring(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """The Voigt spring's law where an effect makes it nonlinear (one at most), else None."""
        springs = [e for e in self.effects if e.nonlinear_spring]
        if len(springs) > 1:
            raise ValueError(f"two effects make the Voigt spring nonlinear: {', '.join(e.id for e in springs)}")
        return springs[0].voigt_spring if springs else None

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        for effect in self.effects:
            force = effect.measured_force(t, force, release)
        return force

    def measured_markers(self, t: np.ndarray, displacement: np.ndarray) -> np.ndarray:
        for effect in self.effects:
            displacement = effect.measured_markers(t, displacement)
        return displacement

    @property
    def memory(self) -> float:
        """The longest past (s) any of its effects' readings depends on (``Effect.memory``)."""
        return max((e.memory for e in self.effects), default=0.0)

    def felt_force(self, t: np.ndarray, force: np.ndarray, strain: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """What the sensor feels over a sampled run: the linear nodal ``force`` (T, nodes)
        scaled by the stress effects at nominal ``strain`` (T,), then the sensor-side
        effects given when ``contact`` (T,) was lost."""
        scaled = force * self.stress_scale(strain)[:, None]
        return self.measured_force(t, scaled, Release.find(t, scaled, contact))

    @property
    def signed_parameters(self) -> tuple[str, ...]:
        """Parameter names that may take either sign (the rest are positive)."""
        return tuple(f"{e.id}.{name}" for e in self.effects for name in e.signed)

    @property
    def parameters(self) -> dict[str, float]:
        out = dict(self.base.parameters)
        for effect in self.effects:
            out.update(effect.parameters)
        return out

    def with_parameters(self, values: Mapping[str, float]) -> Model:
        base_keys = set(self.base.parameters)
        return replace(
            self,
            base=self.base.with_parameters({k: v for k, v in values.items() if k in base_keys}),
            effects=tuple(e.with_parameters(values) for e in self.effects),
        )
