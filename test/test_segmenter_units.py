"""The online segmenter (``rheo_ros.online.segmenter``) on a synthetic stream whose phase
boundaries are known exactly: a stage ramp, hold and retraction, a force proportional
to the depth, markers that follow it and recover exponentially. Fast (no simulation):
mutation testing runs these (``./tasks mutation``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rheo_ros.config.tuning import SegmenterConfig
from rheo_ros.online.segmenter import PhaseSegmenter, _Line, _line, _median, _robust_spread

T_START, DEPTH, VELOCITY, KEEP, RETRACT = 2.0, 0.004, 0.001, 6.0, 0.004   # s, m, m/s, s, m/s
T_PULL_END = T_START + DEPTH / VELOCITY          # 6.0
T_KEEP_END = T_PULL_END + KEEP                   # 12.0
T_BACK = T_KEEP_END + DEPTH / RETRACT            # 13.0
RECOVERY = 1.5                                   # s, the markers' recovery after release


def depth_at(t):
    return np.interp(t, [0, T_START, T_PULL_END, T_KEEP_END, T_BACK, 1e9], [0, 0, DEPTH, DEPTH, 0, 0])


def stream(t_end=40.0, offset=0.0, seed=0, noise=1e-7):
    """(stream, t, value) in stamp order: stage 100 Hz, force 50 Hz, markers 10 Hz."""
    rng = np.random.default_rng(seed)
    ts = np.round(np.arange(0.0, t_end, 0.01), 6)
    tf = np.round(np.arange(0.005, t_end, 0.02), 6)
    tm = np.round(np.arange(0.0, t_end, 0.1), 6)
    shape = np.linspace(0.2, 1.0, 8)
    out = [("stage", t + offset, float(d)) for t, d in zip(ts, depth_at(ts) + rng.normal(0, noise, ts.size))]
    out += [("force", t + offset, float(f)) for t, f in zip(tf, 200.0 * depth_at(tf) + rng.normal(0, 1e-3, tf.size))]
    amp = np.where(tm < T_KEEP_END, depth_at(tm), DEPTH * np.exp(-np.clip(tm - T_KEEP_END, 0, None) / RECOVERY))
    out += [("markers", t + offset, np.outer(shape, [0.1, 1.0]).ravel() * a + rng.normal(0, 1e-7, 16))
            for t, a in zip(tm, amp)]
    return sorted(out, key=lambda m: (m[1], ("stage", "force", "markers").index(m[0])))


def feed(seg, msgs):
    add = {"stage": seg.add_stage, "force": seg.add_force, "markers": seg.add_markers}
    return [e for s, t, v in msgs for e in add[s](t, v)]


def test_line_and_robust_spread():
    line = _Line(10.0)
    assert line.slope() == 0.0
    line.add(10.0, 1.0)
    assert line.slope() == 0.0
    line.add(12.0, 0.0)
    line.add(14.0, -1.0)
    assert line.slope() == pytest.approx(-0.5)
    assert line.time_at(0.5) == pytest.approx(11.0)
    same = _Line(0.0)
    same.add(1.0, 1.0)
    same.add(1.0, 2.0)
    assert same.slope() == 0.0                 # two samples, one time: no slope
    assert _robust_spread(np.array([])) == 0.0
    assert _robust_spread(np.array([1.0, 2.0, 3.0, 100.0])) == pytest.approx(1.4826)


def test_one_push_gives_contact_pull_keep_release_at_the_known_times():
    seg = PhaseSegmenter()
    events = feed(seg, stream())
    assert [e.name for e in events] == ["contact", "pull", "keep", "release"]
    contact, pull, keep, release = events
    assert all(e.experiment == 1 for e in events)
    assert contact.t_start == contact.t_end and T_START < contact.t_start < T_START + 0.1
    assert contact.samples == 0
    assert pull.t_start == pytest.approx(T_START, abs=2e-3) and pull.t_end == pytest.approx(T_PULL_END, abs=2e-3)
    assert T_PULL_END < pull.t_found < T_PULL_END + 0.2
    assert pull.samples == pytest.approx(400, abs=2)
    assert keep.t_start == pull.t_end and keep.t_end == pytest.approx(T_KEEP_END, abs=2e-3)
    assert keep.samples == pytest.approx(600, abs=20)
    assert release.t_start == keep.t_end
    # The mesh settles within its noise some recovery times after the let-go.
    assert T_KEEP_END + 5.0 < release.t_end < T_KEEP_END + 20.0
    assert 0 < release.samples <= 10 * (release.t_end - release.t_start) + 1
    assert seg.release_reason == "settled"
    p = seg.profile
    assert p.depth == pytest.approx(DEPTH, rel=1e-4) and p.velocity == pytest.approx(VELOCITY, rel=1e-3)
    assert p.t_pull_start == pytest.approx(T_START, abs=2e-3)
    assert p.keep_time == pytest.approx(KEEP, abs=4e-3)
    assert p.retract_speed == pytest.approx(RETRACT, rel=1e-3)
    assert p.release_time == pytest.approx(release.t_end - release.t_start)
    assert seg.state == "rest" and seg.contacts == 1 and seg.dropped == {"stage": 0, "force": 0, "markers": 0}


def test_repeated_pushes_are_numbered_and_late_samples_dropped():
    seg = PhaseSegmenter()
    events = feed(seg, stream() + stream(offset=40.0, seed=1))
    assert [(e.experiment, e.name) for e in events] == [
        (k, n) for k in (1, 2) for n in ("contact", "pull", "keep", "release")]
    second = [e for e in events if e.experiment == 2 and e.name == "pull"][0]
    assert second.t_start == pytest.approx(40.0 + T_START, abs=2e-3)
    assert seg.add_stage(10.0, 0.0) == [] and seg.add_stage(100.0, np.nan) == []
    assert seg.add_force(0.0, 1.0) == [] and seg.add_markers(0.0, np.zeros(16)) == []
    assert seg.add_markers(1e3, np.full(16, np.nan)) == []
    assert seg.dropped == {"stage": 1, "force": 1, "markers": 1}


def test_a_twitch_shallower_than_min_depth_is_no_push():
    # 0.5 mm up in 0.5 s, held 0.3 s: a push by its shape, a twitch by min_depth (1 mm).
    seg = PhaseSegmenter(SegmenterConfig(min_depth=1e-3))
    seen = []
    for t in np.round(np.arange(0.0, 2.8, 0.01), 6):
        assert seg.add_stage(float(t), float(np.interp(t, [0, 2.0, 2.5, 9.0], [0, 0, 5e-4, 5e-4]))) == []
        seen.append((seg.state, seg.experiment))
    assert ("pull", 1) in seen
    i = seen.index(("pull", 1))
    assert ("rest", 0) in seen[i:]
    pushed = PhaseSegmenter(SegmenterConfig(min_depth=4e-4))
    events = [e for t in np.round(np.arange(0.0, 2.8, 0.01), 6)
              for e in pushed.add_stage(float(t), float(np.interp(t, [0, 2.0, 2.5, 9.0], [0, 0, 5e-4, 5e-4])))]
    assert [e.name for e in events] == ["pull"] and events[0].t_start == pytest.approx(2.0, abs=2e-3)


def test_a_next_push_before_the_mesh_settles_ends_the_release():
    slow = [m for m in stream(t_end=20.0)]
    seg = PhaseSegmenter(SegmenterConfig(settle_window=30.0))
    events = feed(seg, slow + stream(offset=20.0, seed=2))
    releases = [e for e in events if e.name == "release"]
    pulls = [e for e in events if e.name == "pull"]
    assert releases[0].experiment == 1 and releases[0].t_end < pulls[1].t_start
    assert releases[0].t_end == pytest.approx(19.9 + 0.0, abs=0.11) or releases[0].t_end <= 20.0 + T_START
    assert [e.name for e in events].count("pull") == 2


def test_a_release_settles_only_once_the_stage_stream_has_passed_it():
    """Markers 5 s ahead of a lagging stage stream (a busy publisher over DDS): the mesh
    may look settled on frames the stage has not reached, which may already hold the next
    push. The release ends at the same frame as in stamp order, emitted by the stage
    sample that passes it, not by a marker frame ahead of the stage."""
    in_order = [e for e in feed(PhaseSegmenter(), stream()) if e.name == "release"]
    lagging = sorted(stream(), key=lambda m: m[1] + (5.0 if m[0] == "stage" else 0.0))
    seg, last_stage, found = PhaseSegmenter(), -np.inf, []
    add = {"stage": seg.add_stage, "force": seg.add_force, "markers": seg.add_markers}
    for name, t, v in lagging:
        last_stage = t if name == "stage" else last_stage
        found += [(name, last_stage, e) for e in add[name](t, v) if e.name == "release"]
    [(name, stage_at, release)] = found
    assert name == "stage" and stage_at >= release.t_end
    assert release.t_end == in_order[0].t_end and release.t_start == in_order[0].t_start


def test_a_stage_stream_that_stopped_no_longer_holds_the_release_back():
    """The stage stream stops 1 s after the let-go, the markers go on: no release until the
    caller says the stage went silent (``judge_ahead_of_stage``), then the same end as in
    stamp order."""
    in_order = [e for e in feed(PhaseSegmenter(), stream()) if e.name == "release"]
    seg = PhaseSegmenter()
    events = feed(seg, [m for m in stream() if m[0] != "stage" or m[1] < T_KEEP_END + 1.0])
    assert [e.name for e in events if e.name == "release"] == []
    [release] = seg.judge_ahead_of_stage()
    assert (release.t_start, release.t_end) == (in_order[0].t_start, in_order[0].t_end)
    assert seg.judge_ahead_of_stage() == []


def test_a_release_still_moving_at_max_release_ends_there():
    seg = PhaseSegmenter(SegmenterConfig(max_release=2.0))
    events = feed(seg, stream())
    release = events[-1]
    assert release.name == "release"
    assert 2.0 < release.t_end - release.t_start <= 2.1 + 1e-9
    assert seg.release_reason == "still moving after 2 s"


def test_close_release_ends_an_open_release_at_the_last_frame():
    seg = PhaseSegmenter()
    assert seg.close_release("end of bag") == []
    events = feed(seg, [m for m in stream() if m[1] < T_KEEP_END + 2.0])
    assert events[-1].name == "keep"
    closed = seg.close_release("end of bag")
    assert len(closed) == 1 and closed[0].name == "release"
    assert closed[0].t_end == pytest.approx(T_KEEP_END + 1.9, abs=1e-6)
    assert seg.release_reason == "end of bag"
    assert seg.close_release("again") == []


def test_contact_needs_a_confirmed_rise_above_the_resting_force():
    seg = PhaseSegmenter(SegmenterConfig(confirm=3, contact_force=0.5))
    t = np.arange(0, 2, 0.02)
    for ti in t:
        assert seg.add_force(float(ti), 0.0) == []
    assert seg.add_force(2.00, 1.0) == [] and seg.add_force(2.02, 1.0) == []
    assert seg.add_force(2.04, 0.1) == []                    # a blip: the run restarts
    assert seg.add_force(2.06, 1.0) == [] and seg.add_force(2.08, 1.0) == []
    events = seg.add_force(2.10, 1.0)
    assert len(events) == 1 and events[0].t_start == pytest.approx(2.06) and events[0].t_found == pytest.approx(2.10)
    assert seg.contacts == 1
    # Let go (three readings below), then a second contact.
    for k, f in enumerate([0.0, 0.0, 0.0] + [0.0] * 20 + [1.0, 1.0, 1.0]):
        out = seg.add_force(2.12 + 0.02 * k, f)
    assert seg.contacts == 2 and out[0].experiment == 2


def test_close_release_only_while_a_release_is_open():
    seg = PhaseSegmenter()
    feed(seg, stream())                                  # settled: nothing to close
    assert seg.state == "rest" and seg.close_release("end") == []
    seg = PhaseSegmenter()
    fed = [m for m in stream() if m[0] != "markers" and m[1] < T_KEEP_END + 2.0]
    feed(seg, fed)
    assert seg.state == "release"
    closed = seg.close_release("no markers")            # no frame at all: ends at the let-go
    assert closed[0].t_end == closed[0].t_start
    # Found at the latest sample heard: where a recording's analysis replays the close.
    assert closed[0].t_found == max(m[1] for m in fed)


@given(arrays(np.float64, st.integers(0, 300), elements=st.floats(-1e6, 1e6, allow_nan=False)))
def test_the_baselines_median_is_numpys_to_the_bit(x):
    """The segmenter's median (a partition: numpy's wrapper cost four times the work on
    the baselines it refreshes every few samples) is ``np.median``'s, bit for bit, so the
    phases found do not move; NaN for no values, as numpy's."""
    if x.size == 0:
        assert np.isnan(_median(x))
    else:
        assert _median(x) == float(np.median(x))


@given(st.integers(2, 400), st.floats(-1e3, 1e3), st.floats(-1e-2, 1e-2), st.floats(1e-6, 1e-2),
       st.integers(0, 2**16))
def test_the_baselines_line_is_numpys_least_squares_line(n, intercept, slope, noise, seed):
    """The resting force's line and the plateau's slope (refreshed every few samples, so
    without ``np.polyfit``'s SVD) are the least-squares line: slope within 1e-9 of the
    noise over the span, intercept within 1e-9 of the noise."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.001, 0.02, n))
    y = intercept + slope * t + rng.normal(0.0, noise, n)
    want_slope, want_icept = np.polyfit(t, y, 1)
    got_slope, got_icept = _line(t, y)
    span = t[-1] - t[0]
    assert abs(got_slope - want_slope) * span <= 1e-9 * noise + 1e-12 * abs(intercept)
    assert abs(got_icept - want_icept) <= 1e-9 * noise + 1e-12 * (abs(intercept) + abs(slope) * t[-1])
    assert _line(np.full(3, 2.0), np.arange(3.0)) == (0.0, 1.0)   # times that do not vary: no slope
