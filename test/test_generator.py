"""The independent generator (test/generator.py) is itself right: its mechanics match
the three-element model's closed forms, its bags follow the contract and read back the
same with mcap and with the package's reader, and its noise is seeded."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import generator as g
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.signal import lsim, lti

MAT = g.Material()
PROFILE = g.Profile()
LAYOUT = g.Layout()
H = LAYOUT.height


def closed_form(m: g.Material, p: g.Profile, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stress and strain of the linear three-element block, derived by hand.

    Pull (eps = r t', r = v/H, t' = t - t0): with k = E/(c1+c2), the dashpot strain
    solves eps_d' + k eps_d = k r t' + c1 r/(c1+c2), so eps_v = (r c2/E)(1 - e^{-k t'})
    and sigma = c2 eps_d' = c2 r (1 - c2/(c1+c2) e^{-k t'}).
    Keep: eps_v relaxes with tau_r = (c1+c2)/E and sigma = E c2/(c1+c2) eps_v (to zero).
    Release (free, sigma = 0): eps_d stays, eps_v decays with c1/E.
    """
    E, c1, c2 = m.E, m.c1, m.c2
    t0, t1, t2, _ = p.knots
    r, k = p.velocity / H, E / (c1 + c2)
    ev1 = r * c2 / E * (1 - math.exp(-k * (t1 - t0)))
    ev2 = ev1 * math.exp(-k * (t2 - t1))
    e_d = p.depth / H - ev2
    pull, keep, free = (t >= t0) & (t < t1), (t >= t1) & (t < t2), t >= t2
    sigma, eps = np.zeros_like(t), np.zeros_like(t)
    sigma[pull] = c2 * r * (1 - c2 / (c1 + c2) * np.exp(-k * (t[pull] - t0)))
    eps[pull] = r * (t[pull] - t0)
    sigma[keep] = E * c2 / (c1 + c2) * ev1 * np.exp(-k * (t[keep] - t1))
    eps[keep] = p.depth / H
    eps[free] = e_d + ev2 * np.exp(-E / c1 * (t[free] - t2))
    return sigma, eps


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b) / np.abs(b)))


T = g.sample_times(50.0, PROFILE.knots[3])


def test_stress_and_strain_match_the_closed_form() -> None:
    tr = g.simulate(MAT, g.Effects(), PROFILE, T, H)
    sigma, eps = closed_form(MAT, PROFILE, T)
    t0, t1, t2, _ = PROFILE.knots
    pull, keep, free = (T >= t0) & (T < t1), (T >= t1) & (T < t2), T >= t2
    assert rel(tr.sigma[pull], sigma[pull]) < 1e-6
    assert rel(tr.sigma[keep], sigma[keep]) < 1e-6
    assert rel(tr.eps[T >= t0 + 0.1], eps[T >= t0 + 0.1]) < 1e-6   # the whole record
    assert np.all(tr.sigma[(T < t0) | free] == 0.0) and not tr.contact[free].any()


def test_other_material_and_profile() -> None:
    """Table I's 1D case (E 2, c1 8, c2 40) is far from Table IV: fast relaxation."""
    m, p = g.Material(E=2.0, c1=8.0, c2=40.0), g.Profile(velocity=0.5 / 20 * H, depth=0.5 * H, keep_time=20.0)
    t = g.sample_times(100.0, p.knots[3])
    tr, (sigma, eps) = g.simulate(m, g.Effects(), p, t, H), closed_form(m, p, t)
    on = tr.contact
    assert rel(tr.sigma[on], sigma[on]) < 1e-6 and rel(tr.eps[t > 1.1], eps[t > 1.1]) < 1e-6


def test_maxwell_arms_add_their_closed_form() -> None:
    """In contact an arm (E_i, tau_i) adds E_i tau_i r (1 - e^{-t'/tau_i}) in the pull,
    then relaxes with tau_i in the keep."""
    eff = g.EFFECTS["relaxation_branch"]
    tr = g.simulate(MAT, eff, PROFILE, T, H)
    sigma, _ = closed_form(MAT, PROFILE, T)
    t0, t1, t2, _ = PROFILE.knots
    r = PROFILE.velocity / H
    for Ei, tau in eff.maxwell:
        end = Ei * tau * r * (1 - math.exp(-(t1 - t0) / tau))
        sigma += np.where((T >= t0) & (T < t1), Ei * tau * r * (1 - np.exp(-(T - t0) / tau)), 0.0)
        sigma += np.where((T >= t1) & (T < t2), end * np.exp(-(T - t1) / tau), 0.0)
    on = tr.contact
    assert rel(tr.sigma[on], sigma[on]) < 1e-6


def test_stiffening_law() -> None:
    tiny = g.simulate(MAT, g.Effects(stiffening=1e-9), PROFILE, T, H)
    assert rel(tiny.sigma[tiny.contact], closed_form(MAT, PROFILE, T)[0][tiny.contact]) < 1e-6
    stiff = g.simulate(MAT, g.EFFECTS["strain_stiffening"], PROFILE, T, H)
    i = np.searchsorted(T, PROFILE.knots[1]) - 1   # last sample of the pull
    # Nearly all the pull's strain is in the Voigt spring (c2 is huge): k = 4 at 0.125.
    assert 1.2 < stiff.sigma[i] / tiny.sigma[i] < 1.35


def test_slow_retraction_keeps_contact_until_the_stress_vanishes() -> None:
    p = replace(PROFILE, retract_speed=1e-3)    # slower than the free recovery at first
    t = g.sample_times(100.0, p.knots[3])
    tr = g.simulate(MAT, g.Effects(), p, t, H)
    depth, _ = p.stage(t)
    t2 = p.knots[2]
    follows = tr.contact & (t >= t2)
    assert follows.sum() > 100 and np.all(tr.sigma[follows] >= 0.0)
    np.testing.assert_allclose(tr.eps[follows], depth[follows] / H, rtol=0, atol=1e-12)
    leave = t[follows][-1]
    # At the moment it leaves, the free recovery speed H E eps_v / c1 equals the stage's.
    assert tr.sigma[follows][-1] < 5.0 and 0 < leave - t2 < 10
    free = t > leave
    assert np.all(tr.eps[free] * H >= depth[free] - 1e-12) and np.all(tr.sigma[free] == 0)


def test_sensor_models_and_visible_effects() -> None:
    exact = g.synthesize(sensor="noise_free")
    truth = g.simulate(MAT, g.Effects(), PROFILE, exact.tactile_t, H).sigma
    np.testing.assert_array_equal(exact.images, np.broadcast_to(truth[:, None, None], exact.images.shape)
                                  .astype(np.float32))
    t2 = PROFILE.knots[2]
    adh = g.synthesize(effects=g.EFFECTS["adhesion"], sensor="noise_free").images[:, 0, 0]
    p0, tau = g.EFFECTS["adhesion"].adhesion
    after = exact.tactile_t >= t2
    np.testing.assert_allclose(adh[after], p0 * np.exp(-(exact.tactile_t[after] - t2) / tau), rtol=1e-6)
    drift = g.synthesize(effects=g.EFFECTS["sensor_drift"], sensor="noise_free").images - exact.images
    a, tau_d, _ = g.EFFECTS["sensor_drift"].drift
    shape = drift / (1 - np.exp(-np.maximum(exact.tactile_t, 1e-3) / tau_d))[:, None, None]
    assert np.ptp(shape[10:], axis=0).max() < 1e-2 * a and 0.3 * a < shape[-1].mean() < 1.7 * a
    dflt = g.synthesize(sensor="default_like").images
    assert np.all((dflt == 0) | (dflt >= 300)) and np.all(np.round(dflt / 10) * 10 == dflt)
    quant = g.synthesize(sensor="quantised").images
    assert np.all(np.round(quant / 50) * 50 == quant) and (quant[(quant > 0) & (quant < 300)]).size > 0
    assert g.synthesize(sensor="clipped").images.max() == 4000.0
    nd = g.synthesize(sensor="no_dead_band").images
    assert nd.min() == 0.0 and np.any((nd > 0) & (nd < 100))
    cam = [g.synthesize(sensor=s).markers[:, :, 0] - exact.markers[:, :, 0] for s in ("default_like", "noisy_camera")]
    assert 1.5e-5 < np.std(cam[0]) < 2.5e-5 and 0.8e-4 < np.std(cam[1]) < 1.2e-4


def test_the_other_laws_in_no_catalogue() -> None:
    """BENCH_OUTSIDE_OTHER's laws, noise-free: the exponential damage is the stress times
    exp(-d eps_max) (its largest strain at the end of the pull); the play reads w under
    the pressure while it rises past w and w over it once it has fallen (after the
    release: w); the second-order lag is scipy's lsim of the critically damped system."""
    exact = g.synthesize(sensor="noise_free")
    t, p = exact.tactile_t, exact.images[:, 0, 0].astype(float)
    t1, t2 = PROFILE.knots[1], PROFILE.knots[2]
    eps = g.simulate(MAT, g.Effects(), PROFILE, t, H).eps
    soft = g.synthesize(effects=g.Effects(damage_exponential=2.0), sensor="noise_free").images[:, 0, 0]
    np.testing.assert_allclose(soft, (p * np.exp(-2.0 * np.maximum.accumulate(eps))).astype(np.float32), rtol=1e-6)
    play = g.synthesize(effects=g.Effects(sensor_hysteresis=200.0), sensor="noise_free").images[:, 0, 0]
    rising = (t < t1) & (p > 200.0)
    np.testing.assert_allclose(play[rising], p[rising] - 200.0, rtol=1e-5)
    assert np.all(np.abs(play[t > t2 + 1.0] - 200.0) < 1e-3)
    lagged = g.synthesize(effects=g.Effects(sensor_lag_second_order=(1.0, 0.4)), sensor="noise_free").images[:, 0, 0]
    second = lsim(lti([1.0], [1.0, 2.0, 1.0]), p, t)[1]
    np.testing.assert_allclose(lagged, (0.6 * p + 0.4 * second).astype(np.float32), rtol=1e-5, atol=1e-3)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("generator")
    return {"a": g.generate(root / "a", seed=7), "b": g.generate(root / "b", seed=7),
            "c": g.generate(root / "c", seed=8, params_in_metadata=False)}


def test_bag_reads_back_with_mcap(bags: dict[str, Path]) -> None:
    (mcap,) = bags["a"].glob("*.mcap")
    seen: dict[str, list] = {topic: [] for topic in g.TOPICS}
    with mcap.open("rb") as fh:
        for schema, channel, message, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert message.log_time == stamp and schema.name == g.TOPICS[channel.topic]
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            seen[channel.topic].append((stamp, msg))
    t_end = int(PROFILE.knots[3] * 1e9)
    for topic, count in ((g.STAGE, 16901), (g.TACTILE, 8451), (g.MARKERS, 1691)):
        assert len(seen[topic]) == count and seen[topic][0][0] == 0 and seen[topic][-1][0] == t_end
    js, img, pa = seen[g.STAGE][-1][1], seen[g.TACTILE][0][1], seen[g.MARKERS][0][1]
    assert js.name == ["stage"] and len(js.position) == len(js.velocity) == 1
    assert (img.encoding, img.height, img.width, img.step, img.is_bigendian) == ("32FC1", 6, 32, 128, 0)
    assert img.header.frame_id == "tactile" and pa.header.frame_id == "specimen" and len(pa.poses) == 25
    assert all((p.orientation.w, p.orientation.x) == (1.0, 0.0) for p in pa.poses)
    meta = (bags["a"] / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in meta and "rheo_ros.params" in meta
    assert "rheo_ros.params" not in (bags["c"] / "metadata.yaml").read_text()


def test_bag_reads_back_with_the_package_reader(bags: dict[str, Path]) -> None:
    from rheo_ros.config.setup import parse_params
    from rheo_ros.io.bag import read_bag

    for name, seed in (("a", 7), ("c", 8)):
        path = bags[name]
        params = None if name == "a" else parse_params(path.with_name("c.params.yaml").read_text())
        got, want = read_bag(path, params), g.synthesize(seed=seed)
        rec = got.record
        assert got.params["geometry"] == "uniaxial" and got.params["tactile.cols"] == 32
        np.testing.assert_allclose(rec.stage_t, want.stage_t, rtol=0, atol=1e-12)   # via integer ns
        np.testing.assert_allclose(rec.stage_depth, want.depth, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got.tactile, want.images)
        np.testing.assert_allclose(got.tactile_t, want.tactile_t, rtol=0, atol=1e-12)
        np.testing.assert_allclose(rec.markers, want.markers, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rec.marker_t, want.marker_t, rtol=0, atol=1e-12)


def raw_messages(bag: Path) -> list[tuple[int, int, bytes]]:
    (mcap,) = bag.glob("*.mcap")
    with mcap.open("rb") as fh:
        return [(m.channel_id, m.log_time, bytes(m.data)) for _, _, m in make_reader(fh).iter_messages()]


def test_same_seed_same_bytes_other_seed_other_noise(bags: dict[str, Path]) -> None:
    a, b, c = (raw_messages(bags[k]) for k in "abc")
    assert a == b
    assert len(a) == len(c) and [x[:2] for x in a] == [x[:2] for x in c]
    channel = {name: i + 1 for i, name in enumerate(g.TOPICS)}   # ids in the order written
    t0, _, t2, _ = PROFILE.knots
    for x, y in zip(a, c):
        if x[0] == channel[g.STAGE]:
            assert x == y                                  # the stage has no noise
        elif x[0] == channel[g.MARKERS] or t0 * 1e9 < x[1] < t2 * 1e9:
            assert x != y                                  # other noise (tactile: where above the dead band)


# --- several pushes on one specimen (issue 25) ---

def test_one_push_is_the_default_and_the_profile_checks_its_pushes() -> None:
    assert (PROFILE.pushes, PROFILE.pause) == (1, 0.0) and PROFILE.push_knots(0) == PROFILE.knots
    p = replace(PROFILE, pushes=3, pause=7.0)
    period = p.depth / p.velocity + p.keep_time + p.release_time + p.pause
    assert p.knots[:3] == PROFILE.knots[:3] and p.knots[3] == pytest.approx(PROFILE.knots[3] + 2 * period)
    for bad in ({"pushes": 0}, {"pushes": 2.0}, {"pause": -1.0}, {"pushes": 2, "retract_speed": 1e-4, "release_time": 50.0},
                {"pushes": 2, "pause": 5.0, "fresh": (0,)}, {"pushes": 2, "pause": 5.0, "fresh": (2,)},
                {"pushes": 2, "pause": 2.0, "fresh": (1,)}):
        with pytest.raises(ValueError):
            replace(PROFILE, **bad)


def test_without_a_permanent_set_the_second_push_repeats_the_first() -> None:
    """c2 1e17 (near infinite) and 150 s to recover (30 Voigt times c1/E): push 2's force
    is push 1's shifted by the time between their contacts, to 1e-9 relative (measured
    2.1e-11; what is left is the set integral(sigma)/c2 over eps, 2.1e-9 at c2 = 1e15)."""
    m, p = replace(MAT, c2=1e17), replace(PROFILE, pushes=2, pause=50.0)
    a, b = g.simulate(m, g.Effects(), p, np.zeros(0), H).pushes
    shift = b.contact - a.contact
    assert abs(shift - (b.start - a.start)) < 1e-9           # the stage meets the top at depth ~0
    t = g.sample_times(50.0, a.end)
    tr = g.simulate(m, g.Effects(), p, np.concatenate([t, t + shift]), H)
    s1, s2 = tr.sigma[:t.size], tr.sigma[t.size:]
    on = s1 != 0.0
    assert on.sum() > 3000 and np.all(s2[~on] == 0.0)
    assert rel(s2[on], s1[on]) < 1e-9


def gauss(f, spans: tuple[tuple[float, float], ...], n: int = 40) -> float:
    """Gauss-Legendre with n nodes on each span, f evaluated once on all nodes."""
    x, w = np.polynomial.legendre.leggauss(n)
    nodes = np.concatenate([a + (b - a) * (x + 1) / 2 for a, b in spans])
    weights = np.concatenate([w * (b - a) / 2 for a, b in spans])
    return float(np.sum(weights * f(nodes)))


def test_the_second_push_meets_the_set_the_first_left() -> None:
    """Instant release and 200 s free (39 Voigt times): push 2 meets the top at the
    permanent set eps_d H left by push 1. eps_d = integral of sigma/c2 over push 1's
    contact, computed twice independently: from the closed form (depth/H - eps_v at
    release) and by Gauss-Legendre quadrature of the generator's own stress inside
    each phase (the stress jumps at the knots). Tolerance 1e-9 relative, 100 x the
    integration's rtol 1e-11 (measured: contact depth 4e-16, quadrature and set 2e-14)."""
    p = replace(PROFILE, pushes=2, pause=100.0)
    a, b = g.simulate(MAT, g.Effects(), p, np.zeros(0), H).pushes
    E, c1, c2 = MAT.E, MAT.c1, MAT.c2
    t0, t1, t2, _ = p.push_knots(0)
    r, k = p.velocity / H, E / (c1 + c2)
    ev2 = r * c2 / E * (1 - math.exp(-k * (t1 - t0))) * math.exp(-k * (t2 - t1))
    closed = (p.depth / H - ev2) * H

    def stress(t: np.ndarray) -> np.ndarray:
        return g.simulate(MAT, g.Effects(), p, t, H).sigma / c2

    quadrature = gauss(stress, ((t0, t1), (t1, t2))) * H
    assert abs(quadrature / closed - 1) < 1e-9
    assert closed > 6e-4                                      # 0.65 mm: a set well above the rounding
    for got in (b.contact_depth, b.set_at_start, b.sinking_at_start, a.set_after):
        assert abs(got / closed - 1) < 1e-9
    assert abs(b.contact - (b.start + closed / p.velocity)) < 1e-9 * b.contact
    assert a.leaves == t2 and a.contact == t0 and a.set_at_start == 0.0


def test_a_block_still_recovering_meets_the_stage_later() -> None:
    """Release 5 s, no pause (one Voigt time): push 2 meets the top 3.0 s later than the
    set alone would (at 2.15 mm, not 0.65 mm); the contact is where the closed-form free
    recovery H (eps_d + eps_v e^{-E (t - t_rel)/c1}) meets the stage (1e-9 relative).
    The force is zero up to the contact and the top then follows the stage."""
    p = replace(PROFILE, pushes=2, release_time=5.0)
    t = g.sample_times(100.0, p.knots[3])
    tr = g.simulate(MAT, g.Effects(), p, t, H)
    a, b = tr.pushes
    E, c1, c2 = MAT.E, MAT.c1, MAT.c2
    t0, t1, t2, _ = p.push_knots(0)
    r, k = p.velocity / H, E / (c1 + c2)
    ev2 = r * c2 / E * (1 - math.exp(-k * (t1 - t0))) * math.exp(-k * (t2 - t1))
    ed = p.depth / H - ev2
    from scipy.optimize import brentq
    meet = brentq(lambda s: p.velocity * (s - b.start) - H * (ed + ev2 * math.exp(-E / c1 * (s - t2))),
                  b.start, b.end_pull, xtol=1e-13)
    assert abs(b.contact / meet - 1) < 1e-9 and abs(b.set_at_start / (ed * H) - 1) < 1e-9
    late = b.contact - (b.start + b.set_at_start / p.velocity)
    assert 2.9 < late < 3.1 and b.contact_depth > 3 * b.set_at_start
    before, during = (t >= a.leaves) & (t < b.contact), (t >= b.contact) & (t < b.release)
    assert np.all(tr.sigma[before] == 0.0) and not tr.contact[before].any()
    assert tr.contact[during].all() and np.all(tr.sigma[during] > 0.0)
    np.testing.assert_allclose(tr.eps[during] * H, p.stage(t[during])[0], rtol=0, atol=1e-12)
    assert np.all(tr.eps[before] * H > p.stage(t[before])[0])       # the stage has not reached the top


def test_each_release_has_its_own_adhesion() -> None:
    p = g.Profile(start_delay=1.0, velocity=1e-3, depth=2e-3, keep_time=3.0, release_time=10.0, pushes=2)
    eff = g.Effects(adhesion=(500.0, 20.0))
    clean, sticky = (g.synthesize(effects=e, sensor="noise_free", profile=p) for e in (g.Effects(), eff))
    a, b = sticky.pushes
    t, extra = clean.tactile_t, (sticky.images - clean.images)[:, 0, 0]
    want = np.where((t >= a.release) & (t < b.contact), 500.0 * np.exp(-(t - a.release) / 20.0), 0.0) \
        + np.where(t >= b.release, 500.0 * np.exp(-(t - b.release) / 20.0), 0.0)
    np.testing.assert_allclose(extra, want, rtol=1e-6, atol=1e-3)


def test_a_bag_of_several_pushes(tmp_path: Path) -> None:
    import json

    import yaml
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    p = g.Profile(start_delay=1.0, velocity=1e-3, depth=2e-3, keep_time=3.0, release_time=10.0,
                  retract_speed=2e-3, pushes=3, pause=2.0)
    bag = g.generate(tmp_path / "multi", profile=p, seed=3)
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        conn = [c for c in reader.connections if c.topic == g.STAGE]
        msgs = [store.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages(connections=conn)]
        assert {c.topic for c in reader.connections} == set(g.TOPICS)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    params = yaml.safe_load(meta["custom_data"][g.PARAMS_KEY])["/**"]["ros__parameters"]
    t = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msgs])
    depth, vel = np.array([m.position[0] for m in msgs]), np.array([m.velocity[0] for m in msgs])
    down = np.diff(np.concatenate([[0], (vel > 0).astype(int)]))
    starts = t[down == 1]
    np.testing.assert_allclose(starts, [p.push_knots(i)[0] for i in range(3)], atol=1e-9)
    assert (vel < 0).any() and abs(t[-1] - p.knots[3]) < 1e-9
    for i in range(3):   # every push to the same absolute depth, back to 0 before the next
        s, _, _, e = p.push_knots(i)
        mine = (t >= s) & (t <= e)
        assert depth[mine].max() == pytest.approx(p.depth) and depth[mine][-1] == 0.0
    assert params["stage"] == {"depth": 2e-3, "velocity": 1e-3, "keep_time": 3.0, "start_delay": 1.0,
                               "release_time": 10.0, "retract_speed": 2e-3, "pushes": 3, "pause": 2.0}
    assert "stage" not in g.params_document(LAYOUT, PROFILE)["/**"]["ros__parameters"]
    truth = json.loads(bag.with_name("multi.truth.json").read_text())
    assert truth["profile"]["pushes"] == 3 and len(truth["pushes"]) == 3
    sets = [push["set_at_start"] for push in truth["pushes"]]
    assert sets[0] == 0.0 and 0 < sets[1] < sets[2]
    for push in truth["pushes"]:
        assert push["start"] < push["contact"] or push["index"] == 0
        assert push["phases"]["pull"][0] == push["contact"] and push["phases"]["release"][0] == push["release"]
    assert "pause" in truth["pushes"][1]["phases"] and "pause" not in truth["pushes"][2]["phases"]


@pytest.mark.parametrize("name", ["default_like", "no_dead_band", "clipped", "quantised"])
def test_the_expected_reading_is_the_mean_of_the_sensors_own_readings(name):
    """``expected_reading`` (the bench's separable size reads through it) against the mean
    of 200 000 readings the generator's own chain (``cell_readings``) makes (noise, floor, dead band,
    quantisation, saturation) at pressures from idle to past saturation: within 1 Pa
    (the sample mean's std is 0.22 Pa at 100 Pa noise; quantisation by 10-50 Pa under
    100 Pa of noise averages out to well under that)."""
    sensor = g.SENSORS[name]
    rng = np.random.default_rng(7)
    for p in (0.0, 9.9, 250.0, 300.0, 1000.0, 3950.0, 4100.0):
        mean = g.cell_readings(np.full(200_000, p), sensor, rng).mean()
        assert float(g.expected_reading(np.array([p]), sensor)[0]) == pytest.approx(mean, abs=1.0), p
    # Far above the dead band and under saturation a cell reads its pressure on average.
    assert float(g.expected_reading(np.array([2000.0]), sensor)[0]) == pytest.approx(2000.0, abs=1e-6)
