"""The checks a measurement sample passes before the core takes it, one rule for the
estimator node and ``rheo analyze``: the frame's shape against the parameters, the header
stamps against clock jumps, and the stage's depth and the first marker frame's extent
against the specimen's size (a recording in mm read as m), and NaN or inf in a reading
(dropped silently before: a frame with a NaN cell). Offline a failed check ends
the analysis naming the file and topic (``app.analyze.checked_samples``); online the
message is refused and ``/diagnostics`` names the topic and why.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rheo_ros.config.setup import Setup
from rheo_ros.io.messages import MARKERS_TOPIC, STAGE_TOPIC, TACTILE_TOPIC

# A topic's header stamps going back by more than this (s) is a clock jump, not a reorder
# (the core drops a message older than its stream's last, as a node does).
CLOCK_JUMP = 0.5
# Sizes further than this factor from the parameters' are in other units (mm for m).
UNITS_FACTOR = 10.0


class SampleCheck:
    """What is wrong with each sample of a measurement topic (None: nothing)."""

    def __init__(self, setup: Setup) -> None:
        self.rows, self.cols = setup.tactile.rows, setup.tactile.cols
        self.markers = setup.mesh.nodes.shape
        self.width, self.height = setup.params["specimen.width"], setup.params["specimen.height"]
        self.last: dict[str, float] = {}
        self.spanned = False    # the first marker frame's extent was checked

    def problem(self, topic: str, t: float, data: Any) -> str | None:
        """One line naming what is wrong with ``data`` of ``topic`` (stage depth in m, a
        tactile image (rows, cols) in Pa, marker positions (N, 2) in m) stamped ``t`` s,
        without the topic; None for a good sample, which the check then remembers."""
        last = self.last.get(topic, -np.inf)
        if t < last - CLOCK_JUMP:
            return f"header stamps jump back {last - t:.3g} s at {last:.3f} s (a clock jump: the record cannot be put in order)"
        unfinite = non_finite(topic, t, data)
        if unfinite:
            return unfinite
        if topic == STAGE_TOPIC and data > self.height:
            return (f"position {data:.4g} at {t:.3f} s is deeper than the specimen's height ({self.height:g} m): "
                    "not in m (mm?)")
        if topic == TACTILE_TOPIC and data.shape != (self.rows, self.cols):
            return f"image {data.shape[0]} x {data.shape[1]} at {t:.3f} s, parameters say {self.rows} x {self.cols}"
        if topic == MARKERS_TOPIC:
            if data.shape != self.markers:
                return f"{data.shape[0]} markers at {t:.3f} s, parameters say {self.markers[0]}"
            if not self.spanned:
                span = float(np.max(data[:, 0])) - float(np.min(data[:, 0]))   # inf, not numpy's overflow warning
                if not self.width / UNITS_FACTOR < span < UNITS_FACTOR * self.width:
                    return (f"the markers span {span:.4g} across, the specimen is {self.width:g} m wide: "
                            "not in m (mm?)")
                self.spanned = True
        self.last[topic] = max(t, last)
        return None


def non_finite(topic: str, t: float, data: Any) -> str | None:
    """What is not a number in a sample of ``topic`` (NaN or inf, which no reading can be),
    naming the first such cell or marker; None when every value is finite."""
    if isinstance(data, float):
        if math.isfinite(data):
            return None
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            total = data.sum() if isinstance(data, np.ndarray) else np.sum(data)
        if math.isfinite(total):   # NaN and inf carry through a sum (one pass, no mask)
            return None
    values = np.asarray(data, dtype=float)
    bad = ~np.isfinite(values)
    if not bad.any():   # a sum that overflowed
        return None
    if topic == STAGE_TOPIC:
        return f"position {float(values):g} at {t:.3f} s is not a finite number"
    first = np.argwhere(bad)[0]
    if topic == TACTILE_TOPIC:
        return (f"{int(bad.sum())} reading(s) not finite (NaN or inf) at {t:.3f} s, the first at row {first[0]}, "
                f"col {first[1]}")
    return f"{int(bad.sum())} coordinate(s) not finite (NaN or inf) at {t:.3f} s, the first at marker {first[0]}"
