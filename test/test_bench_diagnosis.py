"""``rheo bench diagnosis``: the result's structure on three short bags, and the
threshold scan on made-up rows."""

from __future__ import annotations

import numpy as np
import pytest

from rheo_ros.bench import diagnosis


def test_two_quick_bags_give_a_complete_confusion_table():
    # Bags cycle through the classes: 0 is clean, 1 carries a hidden effect.
    result = diagnosis.run(replicates=2, seed=4, quick=True)
    bags = result["bags"]
    assert [b["true"] for b in bags] == ["none", "relaxation_branch"]
    assert set(result["confusion"]) == set(diagnosis.CLASSES)
    for counts in result["confusion"].values():
        assert set(counts) == set(diagnosis.COLUMNS)
    assert sum(sum(c.values()) for c in result["confusion"].values()) == 2
    for b in bags:
        assert b["diagnosed"] in diagnosis.COLUMNS, b["message"]
        assert b["diagnosed"] != "failed", b["message"]
        assert b["seconds"] > 0 and b["simulate_seconds"] > 0
        assert np.isfinite(b["size"]) and 0 <= b["size_live"] <= b["size"] * 1.5 + 1e-12
        assert diagnosis.QUICK_KEEP[0] <= b["params"]["stage.keep_time"] <= diagnosis.QUICK_KEEP[1]
    assert bags[0]["size"] == 0.0 and bags[0]["effect"] == {}
    assert bags[1]["size"] > 0 and set(bags[1]["effect"]) == {"stiffness", "viscosity"}
    assert result["clean_bags"] == 1
    # The clean bag is called clean, the hidden relaxation branch named (seed 4, quick bags).
    assert [b["diagnosed"] for b in bags] == ["none", "relaxation_branch"], [b["message"] for b in bags]
    assert result["false_claims_on_clean"] == 0
    assert result["seconds_median"] <= result["seconds_max"]
    table = diagnosis.format_table(result)
    assert "detection threshold" in table
    assert "false claims on clean bags" in table
    assert set(result["per_effect"]) == {"relaxation_branch"}


def _rows(pairs):
    return [{"true": t, "diagnosed": d, "size": s, "size_live": s} for t, d, s in pairs]


def test_the_threshold_is_the_smallest_size_above_which_98_percent_are_right():
    rows = _rows([("adhesion", "none", 0.5), ("adhesion", "adhesion", 1.0), ("sensor_drift", "undecided", 2.0),
                  ("sensor_drift", "sensor_drift", 3.0), ("adhesion", "adhesion", 4.0), ("none", "adhesion", 0.0)])
    t = diagnosis.detection_threshold(rows)
    assert t["threshold"] == 3.0 and t["bags_above"] == 2 and t["accuracy_above"] == 1.0
    assert t["bags_below"] == 3 and t["correct_below"] == 1
    # One error among 60 above still passes 98 %; the clean bag does not count.
    many = _rows([("adhesion", "adhesion", float(s)) for s in range(10, 70)] + [("adhesion", "none", 20.5)])
    assert diagnosis.detection_threshold(many)["threshold"] == 10.0
    assert diagnosis.detection_threshold(_rows([("adhesion", "none", 5.0)]))["threshold"] is None
    # Per effect: adhesion alone is right from 1.0 up, drift from 3.0; absent effects are left out.
    per = diagnosis.per_effect_thresholds(rows)
    assert set(per) == {"adhesion", "sensor_drift"}
    assert per["adhesion"]["threshold"] == 1.0 and per["adhesion"]["bags_below"] == 1
    assert per["sensor_drift"]["threshold"] == 3.0 and per["sensor_drift"]["correct_above"] == 1
    table = diagnosis.confusion(rows)
    assert table["adhesion"]["adhesion"] == 2 and table["none"]["adhesion"] == 1
    assert sum(sum(c.values()) for c in table.values()) == len(rows)


if __name__ == "__main__":
    pytest.main([__file__])
