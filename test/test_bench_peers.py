"""``rheo bench peers``'s generic side (no peer needed): the three-element ODE that
scipy's solve_ivp integrates for least_squares and lmfit, against the model's closed
form under a ramp, a hold and a fast retraction."""

from __future__ import annotations

import numpy as np
import pytest

from rheo_ros.bench.peers import PEERS, drive, three_element_stress

E, C1, C2 = 3.33e4, 1.69e5, 3.11e7
T0, V, T1, T2, VR = 1.0, 5e-4, 21.0, 80.0, -0.02   # start, pull speed, pull end, keep end, retraction (m/s)


def stage(rate: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, 170.0 + 1e-9, 1.0 / rate)
    depth = np.clip(V * (t - T0), 0.0, V * (T1 - T0))
    depth = np.where(t > T2, np.clip(V * (T1 - T0) + VR * (t - T2), 0.0, None), depth)
    return t, depth


def exact(t: np.ndarray) -> np.ndarray:
    """The three-element stress (Pa per m of depth) from rest: a ramp at V, a hold,
    contact lost at once where the stage retracts faster than the specimen recovers."""
    tau, a = (C1 + C2) / E, C1 + C2
    s = np.clip(t - T0, 0.0, T1 - T0)
    ramp = C2 * V * (1.0 - C2 / a * np.exp(-s / tau))
    x1_end = C2 * V / E * (1.0 - np.exp(-(T1 - T0) / tau))
    hold = C2 * E * x1_end / a * np.exp(-(t - T1) / tau)
    return np.select([t <= T0, t <= T1, t <= T2], [0.0, ramp, hold], 0.0)


def test_the_generic_ode_is_the_three_element_closed_form_under_a_ramp_hold_and_release():
    x1_end = C2 * V / E * (1.0 - np.exp(-(T1 - T0) * E / (C1 + C2)))
    assert C1 * VR + E * x1_end < 0   # the retraction pulls at once: contact is lost
    stage_t, depth = stage()
    t_out = np.arange(0.005, 169.0, 0.02)
    got = three_element_stress(t_out, stage_t, depth, E, C1, C2)
    want = exact(t_out)
    assert np.max(np.abs(got - want)) <= 1e-6 * np.max(np.abs(want))
    assert np.all(got[t_out > T2 + 0.01] == 0.0) and got.max() > 0.0


def test_the_drive_is_cut_where_the_stage_changes_its_speed():
    stage_t, depth = stage()
    breaks, d, v = drive(stage_t, depth)
    kinks = [T0, T1, T2, T2 - V * (T1 - T0) / VR]
    assert len(breaks) == len(kinks) + 2
    assert np.allclose(breaks[1:-1], kinks, atol=0.011)
    assert v(10.0) == pytest.approx(V) and d(T2) == pytest.approx(V * (T1 - T0))


def test_the_peers_are_pinned_and_none_is_a_dependency_of_the_package():
    from importlib.metadata import requires

    assert all("==" in pin for pin in PEERS)
    names = {r.split(";")[0].split("[")[0].split("=")[0].split(">")[0].split("<")[0].strip().lower()
             for r in requires("rheo_ros") or []}
    assert not names & {"lmfit", "pyvisco"}

