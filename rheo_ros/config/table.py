"""The package's parameters: one row each, in the order of ``config/rheo_ros.yaml``.

Every default, description and per-value check lives here and nowhere else: the
parameters file's defaults (``setup.DEFAULTS``), the nodes' declarations and
``--help``, and the tuning dataclasses' defaults are derived from this table;
``test/test_config_table.py`` holds ``config/rheo_ros.yaml`` to it. Checks that
involve two parameters or more (rates dividing ``rates.stage``, the depth against
the height, a column per segment) are ``Setup.check``'s.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

# A check takes a value of the parameter's type and says why it cannot be used
# ("0 cells; must be at least 1"), or None when it can.
Check = Callable[[Any], str | None]

# A refined mesh has (refine x cells + 1)^2 nodes: 64 gives 66049 on the 5 x 5 markers,
# far beyond any accuracy gain (`rheo bench mesh`); a larger value only runs out of memory.
MAX_REFINE = 64
# The most nodes a refined mesh may have (mesh.refine and simulator.refine with the
# marker grid, Setup.check): MAX_REFINE's on the default grid; more only runs out of memory.
MAX_NODES = (4 * MAX_REFINE + 1) ** 2
# Markers and tactile cells along one axis: far beyond any rig, and bounded so that a
# typo (1e12 columns) is named here, not met as an allocation of terabytes.
MAX_MARKERS = 4 * MAX_REFINE + 1
MAX_CELLS = 1024
# Specimen sizes (m): a specimen on a bench; 1e300 m overflowed the FE model (issue 21).
SIZE_RANGE = (1e-4, 10.0)


@dataclass(frozen=True)
class Parameter:
    """One parameter: its flat ROS name, its default (whose type is the parameter's),
    what it means (units first), and an optional check of a value on its own."""

    name: str
    default: Any
    help: str
    check: Check | None = None

    def refusal(self, value: Any) -> str | None:
        """Why ``value`` cannot be this parameter's, naming it; None when it can."""
        why = self.check(value) if self.check is not None else None
        return f"{self.name}: {why}" if why else None


def finite(value: float) -> str | None:
    """NaN and infinities reach the models as numbers and fail far from the file."""
    return None if math.isfinite(value) else f"{value}; must be finite"


def positive(value: float) -> str | None:
    return finite(value) or (None if value > 0 else f"{value}; must be positive")


def non_negative(value: float) -> str | None:
    return finite(value) or (None if value >= 0 else f"{value}; must not be negative")


def within(low: float, high: float) -> Check:
    """A finite value from ``low`` to ``high``."""
    def check(value: float) -> str | None:
        return finite(value) or (None if low <= value <= high else f"{value}; must be from {low:g} to {high:g}")
    return check


def size(value: float) -> str | None:
    """A specimen's size in m: positive, and within ``SIZE_RANGE``."""
    low, high = SIZE_RANGE
    return positive(value) or (None if low <= value <= high else f"{value}; must be from {low:g} to {high:g} m")


def poisson(value: float) -> str | None:
    """A Poisson ratio: the FE model's stiffness needs it within (-1, 0.5)."""
    return finite(value) or (None if -1.0 < value < 0.5 else f"Poisson ratio {value} outside (-1, 0.5)")


def positive_or_inf(value: float) -> str | None:
    """Positive, or ``.inf``; NaN is neither."""
    return None if value > 0 else f"{value}; must be positive (.inf: at once)"


def count(least: int, what: str, most: int | None = None) -> Check:
    """An integer count from ``least`` to ``most`` (None: no upper bound) of ``what``."""
    def check(value: int) -> str | None:
        if value < least:
            return f"{value} {what}; must be at least {least}"
        if most is not None and value > most:
            return f"{value} {what}; must be at most {most}"
        return None
    return check


P = Parameter
PARAMETERS: tuple[Parameter, ...] = (
    P("geometry", "plane_fe",
      "uniaxial (homogeneous block in uniaxial stress, paper Sec. II-III: both faces frictionless, gamma from the "
      "markers' lateral motion) or plane_fe (2D plane-stress FE of the face, Sec. IV)"),
    P("boundary.bottom", "bonded",
      "how the bottom face meets the sensor: plane_fe: bonded (no slip) or frictionless (free to slide sideways); "
      "uniaxial: frictionless only (filled in when not set)"),
    P("boundary.top", "bonded",
      "how the top face meets the stage: plane_fe: bonded (no slip) or frictionless (free to slide sideways); "
      "uniaxial: frictionless only (filled in when not set)"),
    P("mesh.refine", 8,
      "identification's FE mesh: each marker-grid element split refine x refine (1: the paper's mesh on the "
      "markers, nodal forces; more: segment forces integrated over their extent; 8: within 0.06 %, "
      f"`rheo bench mesh`); at most {MAX_REFINE}",
      count(1, "splits per element", MAX_REFINE)),
    P("specimen.width", 0.080, "m, along x", size),
    P("specimen.height", 0.080, "m, along y (pushing axis)", size),
    P("specimen.thickness", 0.0125, "m, along z", size),
    P("tactile.rows", 6, "cells along z", count(1, "cells", MAX_CELLS)),
    P("tactile.cols", 32, "cells along x (at least markers.cols: the default's segments P1..P5 have 4, 8, 8, 8, 4 "
                          "columns)", count(1, "cells", MAX_CELLS)),
    P("tactile.noise", 100.0, "Pa, Gaussian per cell (sensor noise)", non_negative),
    P("tactile.resolution", 10.0, "Pa per count (ADC quantisation; 0: none)", non_negative),
    P("tactile.threshold", 300.0,
      "Pa, dead band: readings below it are zero, no tension either (3 x noise keeps an unloaded array at zero)",
      non_negative),
    P("markers.rows", 5, "markers along y", count(2, "markers", MAX_MARKERS)),
    P("markers.cols", 5, "markers along x", count(2, "markers", MAX_MARKERS)),
    P("markers.noise", 2.0e-5, "m, Gaussian per coordinate (one camera pixel)", non_negative),
    P("stage.depth", 0.010, "m, pushing depth (less than specimen.height)", positive),
    P("stage.velocity", 0.0005, "m/s, pull", positive),
    P("stage.keep_time", 48.0, "s, hold at depth", positive),
    P("stage.start_delay", 1.0, "s before pulling (the stage touches the specimen then)", non_negative),
    P("stage.retract_speed", 0.02,
      "m/s on release (.inf: at once); the specimen loses contact when it recovers slower", positive_or_inf),
    P("stage.release_time", 100.0, "s recorded after release until the run is done", positive),
    P("stage.pushes", 1, "pushes on the same specimen, one after the other (the specimen remembers each)",
      count(1, "pushes", 100)),
    P("stage.pause", 0.0, "s at depth 0 between one push's release_time and the next push", non_negative),
    P("stage.driver", "simulated", "motion source: simulated, or a driver registered in rheo_ros.stage_drivers"),
    P("stage.wait_for_subscribers", 0, "stage node: start the run once this many subscribers listen (0: at once)",
      count(0, "subscribers")),
    P("stage.autostart", True, "stage node: run the profile once at start (false: wait for /rheo/identify goals)"),
    P("stage.exit_when_done", False, "stage node: end the process when the profile is done"),
    P("rates.stage", 100.0, "Hz; the simulator samples on its grid", positive),
    P("rates.tactile", 50.0, "Hz, dividing rates.stage", positive),
    P("rates.markers", 10.0, "Hz, dividing rates.stage", positive),
    P("material.E", 3.33e4, "Pa, simulated specimen's spring (paper, Table IV)", positive),
    P("material.c1", 1.69e5, "Pa s, simulated specimen's damper parallel to E (Voigt; paper, Table IV)", positive),
    P("material.c2", 3.11e7, "Pa s, simulated specimen's dashpot in series (paper, Table IV)", positive),
    P("material.gamma", 0.332, "Poisson ratio (paper, Table IV)", poisson),
    P("material.density", 1500.0, "kg/m^3", positive),
    P("simulator.omega", 1000.0, "rad/s, constraint stabilisation (eq. 1)", positive),
    P("simulator.refine", 16,
      "simulator's FE mesh, as mesh.refine (16: 65 x 65 nodes, condensed; finer than the identification's: its "
      f"data are not the identifier's own model); at most {MAX_REFINE}",
      count(1, "splits per element", MAX_REFINE)),
    P("simulator.seed", 0, "noise seed", non_negative),
    P("simulator.effects", [""],
      "hidden effects: relaxation_branch, adhesion, strain_stiffening, sensor_drift (parameters: effects.<id>.*)"),
    P("simulator.clock", False,
      "simulator node: publish /clock and run as fast as possible (stage with use_sim_time)"),
    P("simulator.clock_step", 10, "stage periods the /clock moves on per exchange with the stage (fast mode)",
      count(1, "stage periods")),
    P("simulator.wait_for_subscribers", 0,
      "fast mode: hold /clock until this many subscribers listen to /tactile/pressure and /markers/mesh "
      "(0: at once)", count(0, "subscribers")),
    P("effects.relaxation_branch.stiffness", 3.0e4, "Pa, Maxwell arm", positive),
    P("effects.relaxation_branch.viscosity", 1.5e5, "Pa s (time 5 s at the default stiffness)", positive),
    P("effects.adhesion.fraction", 0.3, "of each node's force at contact loss", within(0.0, 1.0)),
    P("effects.adhesion.time", 200.0, "s, decay of the stuck layer's pressure", positive),
    P("effects.strain_stiffening.coefficient", 4.0, "stress x (1 + coefficient x nominal strain)", finite),
    P("effects.sensor_drift.offset", 0.1, "N per node (~420 Pa per cell: above the dead band)", finite),
    P("effects.sensor_drift.rate", 1.0e-3, "N/s per node", finite),
    P("segmenter.confirm", 3, "samples in a row that confirm a change (push start, leaving the hold, contact)",
      count(1, "samples")),
    P("segmenter.plateau", 10, "flat stage samples that end the pull", count(2, "samples")),
    P("segmenter.flat_slope", 0.2, "a plateau's trend must stay below this fraction of the pull velocity", positive),
    P("segmenter.settle_window", 5.0, "s of marker frames judged for the end of release", positive),
    P("segmenter.settle_fraction", 1.0e-3,
      "motion over the window below this fraction of the push's largest marker motion also counts as settled "
      "(noise-free data)", non_negative),
    P("segmenter.min_depth", 1.0e-4, "m, shallower pushes are encoder noise, not experiments", positive),
    P("segmenter.contact_force", 0.005,
      "N above the resting baseline that counts as contact (with noise, six times the baseline's spread when "
      "larger)", non_negative),
    P("segmenter.max_release", 600.0, "s, a release still moving after this ends anyway (and says so)", positive),
    P("estimator.fit", True, "follow each closed-form update by the whole-record fit of the data so far"),
    P("estimator.undetermined_std", 0.3,
      "relative std above which a parameter is reported as not determined (NaN); gamma is judged on its absolute "
      "std against estimator.gamma_std", positive),
    P("estimator.gamma_std", 0.05, "std of the Poisson ratio above which it is reported as not determined", positive),
    P("estimator.rate_std", 0.3,
      "closed form: relative std of the relaxation rate above which E, c1, c2 are not determined (the force did "
      "not curve enough to show it)", positive),
    P("estimator.pre_contact", 2.0, "s of data kept before each push (the markers' starting positions)", non_negative),
    P("estimator.max_push_time", 3600.0, "s, a longer push is dropped so that memory stays bounded", positive),
    P("estimator.stale_after", 2.0,
      "s of wall clock with no message on any measurement topic after which a release still open is closed as "
      "cut short (and a silent topic stops holding a phase back)", positive),
    P("estimator.release_interval", 10.0,
      "s of data between interim release updates while a release goes on (the specimen still recovering); "
      "0: none", non_negative),
    P("estimator.diagnostics_period", 1.0, "s between /diagnostics messages", positive),
    P("estimator.closed_form_priority", 0,
      "SCHED_FIFO priority (1-99) of the closed-form worker process, so that a phase's closed form does not wait "
      "for a core behind message intake and the fits on a loaded computer (a real-time priority: needs "
      "CAP_SYS_NICE or an rtprio limit; refused, the worker keeps normal scheduling and /diagnostics says so); "
      "0: normal scheduling", count(0, "priority", 99)),
    P("estimator.diagnose", True,
      "after release, find the effect the three-element model misses (rheo analyze's loop, rheo_ros.diagnosis) "
      "and publish the verdict on /rheo/diagnosis"),
)
del P

# Old name -> new name, so that files and bags written under the old name still read:
# "refine" meant the whole-record fit beside mesh.refine's mesh.
RENAMED: dict[str, str] = {"estimator.refine": "estimator.fit"}

BY_NAME: dict[str, Parameter] = {p.name: p for p in PARAMETERS}


def default(name: str) -> Any:
    """The table's default of ``name`` (for the dataclasses whose fields are parameters)."""
    return BY_NAME[name].default
