"""The shape of what a model leaves (``diagnosis.remaining.phase_shape``), on residuals of
known shape with white noise of 0.01 N (50 Hz, 20 s)."""

import numpy as np
import pytest

from rheo_ros.diagnosis.remaining import phase_shape

T = np.arange(0.0, 20.0, 0.02)
NOISE = 0.01


@pytest.mark.parametrize("shape, signal, size", [
    ("none", np.zeros_like(T), 0.0),
    ("step", np.full_like(T, -0.05), -5.0),
    ("ramp", 0.003 * T, 6.0),
    ("decay", 0.08 * np.exp(-T / 3.0), 8.0),
    # exp(-t/4) - exp(-t/1) peaks at 0.47 (t = 1.85 s)
    ("pulse", -0.1 * (np.exp(-T / 4.0) - np.exp(-T / 1.0)), -4.7),
    # the same, 2 s late
    ("pulse", -0.1 * (np.exp(-np.maximum(T - 2, 0) / 4.0) - np.exp(-np.maximum(T - 2, 0) / 1.0)), -4.7),
])
def test_each_shape_is_named_with_its_size_in_noise_units(shape, signal, size):
    """The shape named, its largest excursion within 1 noise unit of the truth's (the
    fitted curve, not a reading), a decay's time within 10 % (measured 2.95 s for 3), a
    pulse's rise and fall times within 20 % and its delay within 0.2 s."""
    got = phase_shape(T, signal + np.random.default_rng(1).normal(0.0, NOISE, T.size), NOISE)
    assert got["shape"] == shape
    assert got["size"] == pytest.approx(size, abs=1.0)
    if shape == "decay":
        assert got["tau"] == pytest.approx(3.0, rel=0.1)
    elif shape == "pulse":   # measured 3.62 s and 1.11 s (the two times trade off under the noise)
        assert got["tau"] == pytest.approx(4.0, rel=0.2) and got["rise"] == pytest.approx(1.0, rel=0.2)
        assert got["delay"] == pytest.approx(T[np.argmax(signal != 0)], abs=0.2)   # measured 0.01, 2.03 s
    else:
        assert got["tau"] is None
    assert (got["rise"] is None) == (shape != "pulse")


def test_a_residual_under_the_decisive_bic_is_no_shape():
    """An offset of 0.1 noise over 1000 readings lowers the chi-square by about 10 - under
    the decisive 10 once its parameter is paid for: none."""
    got = phase_shape(T, 0.1 * NOISE + np.random.default_rng(2).normal(0.0, NOISE, T.size), NOISE)
    assert got["shape"] == "none" and got["size"] == 0.0
