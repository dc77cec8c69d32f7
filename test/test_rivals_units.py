"""The rivals in no catalogue (``models.rivals``): their laws, on their own."""

import numpy as np
import pytest
from scipy.signal import lsim, lti

from rheo_ros.models.effects import catalogue
from rheo_ros.models.rivals import RIVALS, LaggingReading, SensorPlay, StrainSoftening, first_order_lag, play


@pytest.mark.parametrize("time", [0.01, 0.3, 5.0, 1e4])
def test_the_lag_is_scipys_first_order_system_on_a_uniform_grid(time):
    """On a uniform grid, a signal linear between samples through dy/dt = (x - y) / time is
    what scipy's lsim gives (its first-order hold); the closed form over stretches of 30
    times agrees to 1e-9 of the signal's scale, for times from under a sample (0.02 s) to
    far over the record (100 s), every stretch joined (0.01 s: 5000 of them)."""
    t = np.linspace(0.0, 100.0, 5001)
    x = np.column_stack([np.sin(t / 3.0) + 0.1 * t, np.where(t > 40, 1.0, 0.0) * (t - 40)])
    ours = first_order_lag(t, x, time)
    theirs = np.column_stack([lsim(lti([1.0], [time, 1.0]), x[:, j], t, X0=[x[0, j] * time])[1]
                              for j in range(x.shape[1])])
    assert np.max(np.abs(ours - theirs)) < 1e-9 * np.max(np.abs(x))


def test_the_lag_on_an_uneven_grid_is_the_step_by_step_recursion():
    """Jittered stamps (10-30 ms): the step-by-step exact recursion of the README's own
    lag effect, to 1e-12 relative."""
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.01, 0.03, 3000))
    x = rng.normal(size=(3000, 3)).cumsum(axis=0)
    h = np.diff(t)[:, None]
    k = np.exp(-h / 0.4)
    step = x[1:] - k * x[:-1] - np.diff(x, axis=0) * 0.4 / h * (1 - k)
    y = np.empty_like(x)
    y[0] = x[0]
    for i in range(1, len(t)):
        y[i] = k[i - 1] * y[i - 1] + step[i - 1]
    assert np.max(np.abs(first_order_lag(t, x, 0.4) - y)) < 1e-12 * np.max(np.abs(y))


@pytest.mark.parametrize("length", [1, 2, 3, 1000, 4097])
def test_the_play_is_the_step_by_step_clamp(length):
    """The doubling scan is the recursion y_i = clip(y_(i-1), x_i - w, x_i + w) from 0,
    exactly (clip only selects), for a width per column (0: the input itself) and any
    length, a power of two and one over included."""
    rng = np.random.default_rng(length)
    x = rng.normal(size=(length, 4)).cumsum(axis=0)
    width = np.array([[0.0, 0.3, 1.0, 4.0]])
    y, out = np.zeros(4), np.empty_like(x)
    for i in range(length):
        y = np.clip(y, x[i] - width[0], x[i] + width[0])
        out[i] = y
    assert np.array_equal(play(x, width), out)
    assert np.array_equal(play(x, width)[:, 0], x[:, 0])


def test_the_play_is_rate_independent_and_holds_its_width_after_the_release():
    """A push up to 10 and back to 0, slow or fast: the same readings at the same inputs
    (rate-independent); 2 under while loading, 2 over while unloading, 2 held at 0."""
    up = np.linspace(0.0, 10.0, 101)
    x = np.concatenate([up, up[::-1][1:]])[:, None]
    fast = play(x, 2.0)
    slow = play(np.repeat(x, 3, axis=0), 2.0)[::3]
    assert np.array_equal(fast, slow)
    assert fast[100, 0] == 8.0 and fast[-1, 0] == 2.0 and fast[150, 0] == 7.0
    read = SensorPlay(width=0.5, shares=(1.0, 2.0)).measured_force(np.arange(len(x)), np.hstack([x, x]), None)
    assert read[-1].tolist() == [0.5, 1.0]


def test_the_rivals_laws_and_that_they_are_in_no_catalogue():
    """A lagging share of the reading and a stress softened by the largest strain seen;
    none is registered (a rival is never named missing)."""
    t = np.linspace(0.0, 10.0, 1001)
    force = np.where(t < 5.0, 1.0, 0.0)[:, None]
    read = LaggingReading(time=1.0, share=0.2).measured_force(t, force, None)
    assert read[0, 0] == pytest.approx(1.0) and read[499, 0] == pytest.approx(1.0)
    # Off at 5 s (a ramp to 0 over one 10 ms sample): the lagged share then decays over 1 s.
    assert read[-1, 0] == pytest.approx(0.2 * np.exp(-5.0) * (1 - np.exp(-0.01)) / 0.01, rel=1e-9)
    strain = np.array([0.0, 0.1, 0.05, 0.2])
    assert StrainSoftening(2.0).stress_scale(strain) == pytest.approx([1.0, 1 / 1.2, 1 / 1.2, 1 / 1.4])
    assert not {cls.id for cls in RIVALS} & set(catalogue())
