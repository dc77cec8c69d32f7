"""The FE dynamic model (eq. 1, 18-21): exact model response, Fig. 3 behaviour, 2D mesh."""

import numpy as np
import pytest

from rheo_ros.experiment import StageProfile, sample_times
from rheo_ros.fe.dynamic import DynamicFE
from rheo_ros.fe.mesh import Boundary, Mesh, lame_per_unit_modulus
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.models.effects import Model, RelaxationBranch
from rheo_ros.models.elements import three_element
from rheo_ros.models.response import respond, stage_program

TABLE_I = dict(E=2.0, c1=8.0, c2=40.0)


def away_from(t, edges, gap):
    return np.abs(t[:, None] - np.asarray(edges)[None]).min(axis=1) > gap


# Elements with a viscous path at high frequency (the paper's kind). A spring-fronted
# element such as Fig. 8(b) rings on lumped masses: its exact response is pinned in
# test_models instead.
@pytest.mark.parametrize(
    "element",
    [three_element(**TABLE_I), Model(three_element(**TABLE_I), (RelaxationBranch(1.0, 2.0),)).rheology()],
)
def test_uniaxial_fe_matches_exact_model_response(element):
    """The uniaxial block (5 x 5 nodes, frictionless faces) in uniform uniaxial stress:
    the paper's 1D model in every column, and the lateral strain -gamma times the axial."""
    mesh = Mesh.build("uniaxial", 1.0, 1.0, 1.0, rows=5, cols=5)
    gamma = 0.3
    profile = StageProfile.from_times(0.5, 20.0, 20.0, start_delay=1.0, release_time=40.0)
    t = sample_times(profile.t_end, 50.0)
    fe = DynamicFE(mesh, element, gamma, density=1e-3, omega=1e3).simulate(profile, t)
    exact = respond(element, stage_program(profile), t)
    ok = away_from(t, [p.t_start for p in profile.phases], 0.05)
    peak = np.abs(exact.stress).max()
    # Force: unit block, so total force = stress; each node carries its share of the
    # face (1/8 at the edges, 1/4 inside). Tolerance 1e-5 of the peak: the block's
    # inertia (density 1e-3: m*a ~ 4e-6 of the peak while recovering) and the
    # omega-stabilised constraint.
    share = np.array([1, 2, 2, 2, 1]) / 8
    np.testing.assert_allclose(fe.bottom_force[ok], np.outer(exact.stress[ok], share), atol=1e-5 * peak)
    # Every marker moves by the uniform strain field: y sinks with the model's strain,
    # x spreads about the held centre (1e-5 of the depth: inertia while recovering).
    x, y = mesh.nodes[:, 0], mesh.nodes[:, 1]
    strain = exact.strain[ok, None]
    np.testing.assert_allclose(fe.displacement[ok, :, 1], -strain * y, atol=1e-5 * 0.5)
    np.testing.assert_allclose(fe.displacement[ok, :, 0], gamma * strain * (x - 0.5), atol=1e-5 * 0.5)


def test_long_time_case_relaxes_fully_and_keeps_its_deformation(long_case):
    rec, prof = long_case.record, long_case.profile
    f = rec.force.sum(axis=1)                                 # unit block: total force = stress
    end_keep = rec.force_t < prof.t_keep_end
    assert f[end_keep][-1] < 1e-3 * f.max()                   # Fig. 3(a): force relaxed to ~0
    u_top = -rec.marker_displacement[:, -1, 1]
    assert u_top[-1] == pytest.approx(0.5, rel=1e-3)          # no displacement restored


def test_short_time_case_has_residual_force_and_recovery(short_case):
    rec, prof = short_case.record, short_case.profile
    f = rec.force.sum(axis=1)
    keep_last = f[rec.force_t < prof.t_keep_end][-1]
    assert keep_last > 0.3 * f.max()                          # Fig. 3(b): residual force
    u_top = -rec.marker_displacement[:, -1, 1]
    # Recovered displacement (eq. 12): (c1+c2)/(E c2) * F_K(end) on the unit block.
    recovered = 0.5 - u_top[-1]
    assert recovered == pytest.approx((8 + 40) / (2 * 40) * keep_last, rel=2e-3)


def test_force_jump_at_end_of_pull_is_eq10(short_case):
    rec, prof = short_case.record, short_case.profile
    t, f = rec.force_t, rec.force.sum(axis=1)
    before = f[np.searchsorted(t, prof.t_pull_end) - 1]
    after = f[np.searchsorted(t, prof.t_pull_end) + 1]
    eta_rate = 8 * 40 / 48 * 0.5 / 20
    r = 2 / 48
    # One sample (0.02 s) either side of t_P: the force moves by the relaxation meanwhile.
    assert before - after == pytest.approx(eta_rate, rel=2 * 0.02 * r + 1e-4)


def test_plane_stiffness_has_rigid_modes_and_symmetry():
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    K = mesh.stiffness(0.3).toarray()
    np.testing.assert_allclose(K, K.T, atol=1e-12 * np.abs(K).max())
    w = np.linalg.eigvalsh(K)
    assert np.sum(np.abs(w) < 1e-10 * w.max()) == 3         # two translations, one rotation
    shift = np.tile([1.0, 0.0], 25)
    assert np.abs(K @ shift).max() < 1e-12 * np.abs(K).max()


def test_plane_stress_lame_constants():
    lam, mu = lame_per_unit_modulus(0.25)
    assert lam == pytest.approx(0.25 / (1 - 0.0625))
    assert mu == pytest.approx(0.4)
    with pytest.raises(ValueError):
        lame_per_unit_modulus(0.5)


@pytest.mark.parametrize("refine", [1, 3])
@pytest.mark.parametrize("geometry", ["uniaxial", "plane_fe"])
def test_frictionless_block_is_the_analytic_uniaxial_solution(geometry, refine):
    """Both faces frictionless (geometry uniaxial, or plane_fe with that choice): uniform
    uniaxial stress (plane stress), exact on any Q4 mesh. Total force E A d / H, lateral
    expansion gamma d W / H, each tactile segment the uniform pressure times its width,
    markers read by interpolation."""
    mesh = Mesh.build(geometry, 0.08, 0.08, 0.0125, 5, 5, Boundary("frictionless", "frictionless"))
    gamma, depth = 0.3, 0.001
    edges = np.array([0.0, 0.01, 0.03, 0.05, 0.07, 0.08])
    shape = QuasiStaticFE(mesh, refine, edges).shape(gamma)
    pressure = 1.0 * 1.0 / 0.08          # Pa per unit E per unit depth
    np.testing.assert_allclose(shape.bottom_force, pressure * np.diff(edges) * 0.0125, rtol=1e-10)
    x, y = mesh.nodes[:, 0], mesh.nodes[:, 1]
    np.testing.assert_allclose(shape.displacement[:, 1] * depth, -depth * y / 0.08, atol=1e-15)
    np.testing.assert_allclose(shape.displacement[:, 0] * depth, gamma * depth * (x - 0.04) / 0.08, atol=1e-15)


@pytest.mark.parametrize("gamma", [0.3123456789, -0.8987654321, 0.4494321])
def test_shape_between_solved_ratios_is_exact_and_does_not_depend_on_what_came_before(gamma):
    """A ratio off the Taylor grid takes the fifth-order step from the grid point: equal to
    a direct solve within 1e-10 relative, a millionth of the tactile noise (~1e-3 of the
    force) and far above rounding on any CPU (the step's own error ~(5e-4)^6 u^(6)/6!;
    measured 4e-14 on the default mesh; a first-order step on this grid errs by 4e-8 and
    fails), and the same whatever was solved before (an online fit and an offline one must
    agree)."""
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5, Boundary("bonded", "bonded"))
    edges = np.linspace(0.0, 0.08, 6)
    fresh = QuasiStaticFE(mesh, 3, edges)
    busy = QuasiStaticFE(mesh, 3, edges)
    for g in (gamma - 3e-4, gamma + 4e-4, 0.2, gamma - 1e-9):
        busy.shape(g)
    exact = fresh._solve_shape(gamma)[0]
    for fe in (fresh, busy):
        s = fe.shape(gamma)
        np.testing.assert_allclose(s.bottom_force, exact.bottom_force, rtol=1e-10, atol=0)
        np.testing.assert_allclose(s.displacement, exact.displacement, rtol=0,
                                   atol=1e-10 * np.abs(exact.displacement).max())
    np.testing.assert_array_equal(fresh.shape(gamma).bottom_force, busy.shape(gamma).bottom_force)
    # The derivative in the ratio is the one a central difference of direct solves gives.
    slope = fresh._solve_shape(gamma)[1]
    h = 1e-4
    central = (fresh._solve_shape(gamma + h)[0].bottom_force - fresh._solve_shape(gamma - h)[0].bottom_force) / (2 * h)
    np.testing.assert_allclose(slope.bottom_force, central, rtol=1e-6)


def test_tabulated_shape_is_within_1e_5_of_the_solved_one():
    """Figures and live overlays take the shape from the Chebyshev table (no solve): within
    1e-5 relative (measured up to 8e-6, at gamma -0.5: the interpolation's own error, not
    rounding), a hundredth of the tactile noise they are compared with."""
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5, Boundary("bonded", "bonded"))
    fe = QuasiStaticFE(mesh, 3, np.linspace(0.0, 0.08, 6))
    for gamma in (-0.5, 0.0, 0.3123, 0.49):
        exact, table = fe.shape(gamma), fe.tabulated_shape(gamma)
        np.testing.assert_allclose(table.bottom_force, exact.bottom_force, rtol=1e-5)
        np.testing.assert_allclose(table.displacement, exact.displacement, rtol=0,
                                   atol=1e-5 * np.abs(exact.displacement).max())


def test_bonded_faces_restrain_the_lateral_expansion():
    """Bonded top and bottom: the block bulges at mid-height only and is stiffer than
    the frictionless one (the faces cannot expand); the segments are symmetric."""
    free = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5, Boundary("frictionless", "frictionless"))
    bonded = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    edges = np.array([0.0, 0.01, 0.03, 0.05, 0.07, 0.08])
    s_free, s_bonded = (QuasiStaticFE(m, 2, edges).shape(0.332) for m in (free, bonded))
    assert s_bonded.bottom_force.sum() > 1.01 * s_free.bottom_force.sum()
    np.testing.assert_allclose(s_bonded.bottom_force, s_bonded.bottom_force[::-1], rtol=1e-10)
    ux = s_bonded.displacement[:, 0].reshape(5, 5)
    np.testing.assert_allclose(ux[[0, -1]], 0.0, atol=1e-15)           # bottom and top rows held
    assert ux[2, -1] > 0 > ux[2, 0]                                      # bulges sideways


def test_plane_dynamic_fe_matches_quasistatic_limit(plane_case):
    rec, prof, truth = plane_case.record, plane_case.profile, plane_case.truth
    model = Model(three_element(truth["E"], truth["c1"], truth["c2"]))
    pred = QuasiStaticFE(rec.mesh).predict(model, truth["gamma"], prof, rec.force_t, rec.marker_t)
    ok = away_from(rec.force_t, [p.t_start for p in prof.phases], 0.05)
    peak = np.abs(rec.force).max()
    np.testing.assert_allclose(rec.force[ok], pred.force[ok], atol=1e-5 * peak)
    near = away_from(rec.marker_t, [p.t_start for p in prof.phases], 0.15)
    np.testing.assert_allclose(rec.marker_displacement[near], pred.displacement[near], atol=1e-5 * prof.depth)


def _release_run(retract_speed):
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    profile = StageProfile(keep_time=10.0, release_time=20.0, retract_speed=retract_speed)
    fe = DynamicFE(mesh, three_element(3.33e4, 1.69e5, 3.11e7), 0.332)
    t = sample_times(profile.t_end, 100.0)
    return profile, t, fe.simulate(profile, t)


def test_fast_retraction_loses_contact_at_once_then_recovers_freely():
    profile, t, r = _release_run(0.02)   # 20 mm/s: faster than the specimen recovers
    lost = t[np.flatnonzero(~r.contact & (t > profile.t_pull_start))[0]]
    assert profile.t_keep_end <= lost <= profile.t_keep_end + 0.02
    after = t > lost + 0.1
    assert np.abs(r.bottom_force[after]).max() < 1e-3 * r.bottom_force.max()   # stress-free
    top = r.strain[after]
    assert np.all(np.diff(top) <= 1e-12)                                      # recovering


def test_slow_retraction_keeps_contact_while_the_specimen_can_follow():
    profile, t, r = _release_run(1e-3)   # 1 mm/s: the specimen (recovering at ~2 mm/s) keeps up at first
    release = t >= profile.t_keep_end
    in_contact = release & r.contact
    assert t[in_contact].max() > profile.t_keep_end + 0.5
    # Following the stage: the top sinks by the stage depth, and the stage still presses.
    np.testing.assert_allclose(r.strain[in_contact] * 0.08, r.stage_depth[in_contact], atol=1e-6)
    assert np.all(r.bottom_force[in_contact].sum(axis=1) > 0)
    lost = release & ~r.contact
    assert lost.any()                                                        # and then it lets go
    assert np.all(r.strain[lost] * 0.08 >= r.stage_depth[lost] - 1e-9)     # the stage is above it


@pytest.mark.parametrize("retract_speed", [1e-3, 0.02, np.inf])
def test_block_steps_give_the_step_by_step_run(monkeypatch, retract_speed):
    """``simulate`` propagates stretches of equal steps ``BLOCK`` at a time (the same
    linear map, other rounding); two pushes, the stage leaving the specimen and coming
    back onto it (at 1 mm/s it lets go 4.7 s into a slow retraction: inside a block),
    must give the step-by-step run's samples. Measured: 6e-12 of the peak force, 1e-13
    m (1e-11 of the push's depth); tolerances (other CPUs round the sums otherwise) 1e-9
    of the peak force and 1e-9 of the depth, and 1e-6 of the peak within two samples of
    a change of contact (its instant, found to dt / 2^24, may move by that unit). Markers asked at some samples only are
    those samples' and NaN elsewhere."""
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    push = StageProfile(keep_time=3.0, release_time=12.0, retract_speed=retract_speed)
    profile = StageProfile.repeated(push, 2, 1.0)
    element, gamma = three_element(3.33e4, 1.69e5, 3.11e7), 0.332
    t = sample_times(profile.t_end, 100.0)
    every_tenth = np.arange(t.size) % 10 == 0
    blocks = DynamicFE(mesh, element, gamma).simulate(profile, t, every_tenth)
    monkeypatch.setattr(DynamicFE, "BLOCK", 2**40)   # no stretch that long: every step alone
    steps = DynamicFE(mesh, element, gamma).simulate(profile, t)
    assert (blocks.contact == steps.contact).all() and (~steps.contact).any()
    peak = np.abs(steps.bottom_force).max()
    # Where the contact changes, a unit of dt / 2^24 in the instant moves the force by
    # the stage's speed x that time x the stiffness (3.3e-9 of the peak measured).
    event = np.convolve(np.diff(steps.contact.astype(int), prepend=1) != 0, np.ones(5), "same") > 0
    np.testing.assert_allclose(blocks.bottom_force[~event], steps.bottom_force[~event], rtol=0, atol=1e-9 * peak)
    np.testing.assert_allclose(blocks.bottom_force[event], steps.bottom_force[event], rtol=0, atol=1e-6 * peak)
    np.testing.assert_allclose(blocks.strain, steps.strain, rtol=0, atol=1e-9 * push.depth / mesh.height)
    np.testing.assert_allclose(blocks.displacement[every_tenth], steps.displacement[every_tenth], rtol=0,
                               atol=1e-9 * push.depth)
    assert np.isnan(blocks.displacement[~every_tenth]).all()


def test_a_nonlinear_voigt_springs_response_is_solved_once_for_a_model_rebuilt_with_its_values(monkeypatch):
    """A fit rebuilds its model at every evaluation; a Voigt-spring stiffening's response
    is an ODE solve (``respond_voigt_spring``). Asked again with an equal model (a new
    effect object of the same coefficient) and another Poisson ratio, the forward model
    solves nothing and predicts the forces of a fresh solve (within 1e-9 of the peak force); another coefficient
    is solved anew."""
    import rheo_ros.fe.quasistatic as quasistatic
    from rheo_ros.models.effects import VoigtSpringStiffening

    solves = []
    real = quasistatic.respond_voigt_spring
    monkeypatch.setattr(quasistatic, "respond_voigt_spring", lambda *a: solves.append(1) or real(*a))
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    profile = StageProfile(keep_time=6.0, release_time=8.0)
    t = np.linspace(0.0, profile.t_end, 400)
    model = lambda k: Model(three_element(3e4, 3e5, 3e7), (VoigtSpringStiffening(k),))   # noqa: E731
    forward = QuasiStaticFE(mesh)
    first = forward.predict(model(0.8), 0.30, profile, t, t[::4])
    again = forward.predict(model(0.8), 0.31, profile, t, t[::4])
    assert len(solves) == 1
    fresh = QuasiStaticFE(mesh).predict(model(0.8), 0.31, profile, t, t[::4])
    peak = np.abs(fresh.force).max()
    np.testing.assert_allclose(again.force, fresh.force, rtol=0, atol=1e-9 * peak)
    assert np.abs(first.force - again.force).max() > 1e-4 * peak   # the ratio did move the forces
    forward.predict(model(0.9), 0.31, profile, t, t[::4])
    assert len(solves) == 3   # the fresh forward model's, and the new coefficient's


def test_a_voigt_spring_of_an_unhashable_effect_is_solved_each_time_and_right():
    """A user's effect need not be hashable: its spring is then solved at every call, not
    kept, and the response is the solver's own."""
    from rheo_ros.models.response import respond_voigt_spring

    class Law:
        __hash__ = None   # an effect written as a plain, mutable class

        def spring(self, eps):
            return np.expm1(0.7 * eps) / 0.7

    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    profile = StageProfile(keep_time=6.0, release_time=8.0)
    t = np.linspace(0.0, profile.t_end, 300)
    element = three_element(3e4, 3e5, 3e7)
    forward = QuasiStaticFE(mesh)
    got = forward._response(element, profile, t, Law().spring)
    want = respond_voigt_spring(element, Law().spring, mesh.height, stage_program(profile), t)
    np.testing.assert_allclose(got.stress, want.stress, rtol=0, atol=1e-9 * np.abs(want.stress).max())
    assert not forward._responses


@pytest.mark.parametrize("contact", ["held", "free"])
@pytest.mark.parametrize("arms", [0, 1])
def test_the_modal_flow_is_the_whole_systems_matrix_exponential(contact, arms):
    """The model is propagated in parts (the held dofs, each free mode of ``M^-1 K`` with
    what drives it: ``_Split``), not by the matrix exponential of the whole system. On the
    5 x 5 plane mesh (152 states; 202 with an arm), 300 steps of 10 ms from a state with
    every variable loaded (the stage moving) agree with that exponential's. Measured with
    an arm, free: 3.2e-8 of the largest readout (force, sinking, pressing, markers) apart;
    against a 30-digit reference (mpmath, not a dependency) the parts are within 1.9e-12
    and the whole exponential 3.2e-8 (its scaling and squaring over the stiff modes).
    Tolerance 1e-6 of the largest readout: 30 x that rounding, for other CPUs' kernels,
    while a wrong coupling term costs whole percents."""
    from scipy.linalg import expm

    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, 5, 5)
    element = three_element(3.33e4, 1.69e5, 3.11e7)
    if arms:
        element = Model(element, (RelaxationBranch(8e3, 2.4e4),)).rheology()
    fe = DynamicFE(mesh, element, 0.332)
    rng = np.random.default_rng(3)
    z = rng.normal(size=fe.size) * 1e-4
    z[fe.ig], z[fe.igd] = -2e-3, -5e-4
    dt, steps = 0.01, 300
    whole = expm(fe._mode(contact)[0] * dt)
    flow = fe._flow(contact, dt)
    by_parts, by_whole = z.copy(), z.copy()
    for _ in range(steps):
        by_parts, by_whole = fe._step(contact, by_parts, flow), whole @ by_whole
    rows = np.vstack(fe._readout(contact))
    np.testing.assert_allclose(rows @ by_parts, rows @ by_whole, rtol=0, atol=1e-6 * np.abs(rows @ by_whole).max())
    np.testing.assert_allclose(by_parts, by_whole, rtol=0, atol=1e-6 * np.abs(by_whole).max())
    # And a block of equal steps is those steps one by one (6e-12 of the peak force measured
    # on the block test's pushes; 1e-9 of the largest state allowed).
    block = fe._propagate(contact, z, flow, fe.BLOCK)
    one_by_one = [z]
    for _ in range(fe.BLOCK):
        one_by_one.append(fe._step(contact, one_by_one[-1], flow))
    np.testing.assert_allclose(block, np.array(one_by_one[1:]), rtol=0, atol=1e-9 * np.abs(block).max())


def test_a_mesh_unpickled_again_is_the_processs_one_copy_with_its_stiffness():
    # Each job crosses to the closed-form worker with its record's mesh: the second one
    # must come back as the first, its assembled stiffness with it (not assembled again).
    import pickle

    mesh = Mesh.build("plane_fe", 0.08, 0.04, 0.0125, 5, 5)
    first = pickle.loads(pickle.dumps(mesh))
    parts = first.stiffness_parts
    again = pickle.loads(pickle.dumps(mesh))
    assert again is first and again.stiffness_parts is parts
    assert (again.geometry, again.rows, again.cols, again.boundary) == (mesh.geometry, 5, 5, mesh.boundary)
    assert np.array_equal(again.nodes, mesh.nodes)
    other = pickle.loads(pickle.dumps(Mesh.build("plane_fe", 0.08, 0.04, 0.0125, 5, 5, Boundary("frictionless"))))
    assert other is not first and other.boundary == Boundary("frictionless")
    moved = Mesh(mesh.geometry, mesh.width, mesh.height, mesh.thickness, mesh.rows, mesh.cols,
                 mesh.nodes + 1e-6, mesh.boundary)
    assert pickle.loads(pickle.dumps(moved)) is not first
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(moved)).nodes, mesh.nodes + 1e-6)
