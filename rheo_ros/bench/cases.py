"""The paper's simulation cases (Table I) and its 2D experiment (Table IV), as records."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rheo_ros.config.setup import Setup, check_params
from rheo_ros.experiment import StageProfile
from rheo_ros.record import Record
from rheo_ros.rig.simulator import simulate_clean

# Table I: E, c1, c2 and d in the paper's units; a unit block (1 x 1 x 1) makes the
# total force equal the stress and the top's sinking the strain, as in the paper's
# Sections II-III. The paper's 1D model has no Poisson effect: gamma 0.
TABLE_I = {"E": 2.0, "c1": 8.0, "c2": 40.0}
TABLE_I_DEPTH = 0.5
TABLE_I_GAMMA = 0.0
TABLE_IV = {"E": 3.33e4, "c1": 1.69e5, "c2": 3.11e7, "gamma": 0.332}
# Tables II and III: the paper's identified values and errors (%).
TABLE_II = {"E": (2.0006, 0.03), "c1": (8.0107, 0.134), "c2": (40.005, 0.0125)}
TABLE_III = {"E": (2.0046, 0.23), "c1": (8.0098, 0.123), "c2": (40.134, 0.335)}
TABLE_IV_DEFORMATION_ERROR = 0.064  # %


@dataclass(frozen=True)
class Case:
    name: str
    truth: dict[str, float]
    paper: dict[str, tuple[float, float | None]]
    method: str
    record: Record
    profile: StageProfile
    density: float


def simulated(params: dict[str, Any], source: str) -> tuple[Setup, Record]:
    """The package's simulator on the dynamic FE model at the marker grid (refine 1, as
    the paper), noise-free: the setup and its record."""
    setup = Setup(check_params({"simulator.refine": 1, **params}, source))
    return setup, simulate_clean(setup).record(setup, source)


def table_i_case(name: str, phase_time: float) -> Case:
    """Table I long-time (200 s) or short-time (20 s) case on the uniaxial block (the
    paper's homogeneous 1D model), 5 x 5 markers, gamma 0.

    The block's density is 1e-3 kg/m^3: the paper gives no masses, and the
    identification assumes a quasi-static block.
    """
    setup, record = simulated({
        "geometry": "uniaxial", "specimen.width": 1.0, "specimen.height": 1.0, "specimen.thickness": 1.0,
        **{f"material.{k}": v for k, v in TABLE_I.items()}, "material.gamma": TABLE_I_GAMMA, "material.density": 1e-3,
        "stage.depth": TABLE_I_DEPTH, "stage.velocity": TABLE_I_DEPTH / phase_time, "stage.keep_time": phase_time,
        "stage.start_delay": 1.0, "stage.release_time": 100.0, "stage.retract_speed": float("inf"),
    }, f"table_I_{name}")
    paper, method = (TABLE_II, "long_time") if name == "long" else (TABLE_III, "short_time")
    return Case(f"Table I {name}-time (1D)", dict(TABLE_I), paper, method, record, setup.profile, 1e-3)


def table_iv_case() -> Case:
    """The contract's default experiment (80 x 80 x 12.5 mm clay, 5 x 5 markers, push 10 mm
    at 0.5 mm/s, keep 48 s) with the Table IV parameters, on the 2D FE mesh."""
    setup, record = simulated({**{f"material.{k}": v for k, v in TABLE_IV.items()},
                               "stage.retract_speed": float("inf")}, "table_IV_2d")
    paper = {k: (v, None) for k, v in TABLE_IV.items()}  # identified on real clay: no error
    return Case("Table IV parameters (2D)", dict(TABLE_IV), paper, "short_time", record, setup.profile,
                setup.params["material.density"])
