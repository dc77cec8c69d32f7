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
