"""``+onestep`` (seed paper 001, one-step prediction of P) on the navigation problem, at the navigator level.

What the suffix must do (seed 001 sec 2.1, eqs 19-20, multiplication method): the INS still runs at the IMU
rate; the covariance is propagated once per GNSS epoch with the product of the per-sample transitions
``Phi = Phi_n ... Phi_1`` and the *summed* process noise ``Q = sum_i Q_i`` (not propagated through the
``Phi_i``). Without the suffix the navigator composes the per-sample predictions exactly
(``Q = Phi_n (... (Phi_1 0 Phi_1^T + Q_1) ...) Phi_n^T + Q_n``), which must equal a predict at every sample.

The accuracy test is the issue's acceptance criterion: horizontal RMSE of ``+onestep`` within 3% of the
per-sample propagation on ``seed000-sim`` and ``open-sky``, for ``kf`` and one SVD form (``svd-kf``), with
N = 4 paired episodes of the full scenario length (60 s and 300 s). Few episodes suffice because the
comparison is paired (same truth and sensor errors for both) and the one-step error is systematic, not
statistical: with 100 IMU samples per epoch the neglected terms are O(F dt) ~ 1e-4 relative per epoch
(measured RMSE changes ~1e-4, far inside 3%); the test also requires the results to differ at all, so an
ignored suffix fails it.
"""
import numpy as np
import pytest

from envs.episodes import navigator_for, run_episodes
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world

N_EPISODES = 4
SAMPLES = 100  # one 1 s open-sky epoch at 100 Hz


def _spy(nav):
    """Record every (Phi, Q) the navigator hands to its form's predict."""
    calls = []
    orig = nav.form.predict

    def predict(Phi, Q):
        calls.append((np.array(Phi, np.float64), np.array(Q, np.float64)))
        return orig(Phi, Q)

    nav.form.predict = predict
    return calls


@pytest.fixture(scope="module")
def epoch_world():
    return generate_world(get_scenario("open-sky", duration_s=3.0), [11, 12])


def test_onestep_hands_the_product_of_transitions_and_the_summed_Q(epoch_world):
    w = epoch_world
    f, g = w.imu.f_b[:, 1:SAMPLES + 1], w.imu.w_b[:, 1:SAMPLES + 1]
    per = navigator_for(w, "kf")           # reference: one predict per IMU sample
    calls_per = _spy(per)
    P0 = np.array(per.covariance)
    for k in range(SAMPLES):
        per.propagate(f[:, k], g[:, k], 0.01)
        per.flush_prediction()
    one = navigator_for(w, "kf+onestep")
    calls_one = _spy(one)
    one.propagate_epoch(f, g, 0.01)
    one.flush_prediction()
    exact = navigator_for(w, "kf")
    calls_exact = _spy(exact)
    exact.propagate_epoch(f, g, 0.01)
    exact.flush_prediction()

    assert len(calls_per) == SAMPLES and len(calls_one) == 1 and len(calls_exact) == 1
    Phi_prod = np.broadcast_to(np.eye(17), P0.shape).copy()
    Q_sum = np.zeros_like(P0)
    Q_comp = np.zeros_like(P0)
    for Phi_i, Q_i in calls_per:
        Phi_prod = Phi_i @ Phi_prod
        Q_sum += Q_i
        Q_comp = Phi_i @ Q_comp @ Phi_i.mT + Q_i
    Phi1, Q1 = calls_one[0]
    PhiX, QX = calls_exact[0]
    # the one-step prediction: product of the transitions, process noise summed (seed 001 eqs 19-20)
    np.testing.assert_allclose(Phi1, Phi_prod, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Q1, Q_sum, rtol=1e-12, atol=1e-24)
    # without the suffix: the exact composition
    np.testing.assert_allclose(PhiX, Phi_prod, rtol=0, atol=1e-12)
    np.testing.assert_allclose(QX, Q_comp, rtol=1e-10, atol=1e-22)
    # the two process noises are really different (else this test could not tell them apart)
    assert np.abs(Q1 - QX).max() > 1e-4 * np.abs(QX).max()
    # the form receives them as they are: P = Phi P0 Phi^T + sum Q_i, and exact == per-sample prediction
    np.testing.assert_allclose(one.covariance, Phi_prod @ P0 @ Phi_prod.mT + Q_sum, rtol=1e-10, atol=1e-20)
    np.testing.assert_allclose(exact.covariance, per.covariance, rtol=1e-9, atol=1e-18)
    # the INS runs at the IMU rate in every mode: the same nominal state after the epoch
    for a in (one, exact):
        np.testing.assert_allclose(a.r, per.r, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.v, per.v, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.C, per.C, rtol=0, atol=1e-14)


def test_onestep_svd_form_gets_the_same_one_step_prediction(epoch_world):
    """An SVD form with '+onestep' propagates its factors with the same (Phi, sum Q): same P as kf+onestep."""
    w = epoch_world
    f, g = w.imu.f_b[:, 1:SAMPLES + 1], w.imu.w_b[:, 1:SAMPLES + 1]
    kf, svd = navigator_for(w, "kf+onestep"), navigator_for(w, "svd-kf+onestep")
    c_kf, c_svd = _spy(kf), _spy(svd)
    for nav in (kf, svd):
        nav.propagate_epoch(f, g, 0.01)
        nav.flush_prediction()
    np.testing.assert_array_equal(c_kf[0][1], c_svd[0][1])
    P = np.asarray(kf.covariance)
    np.testing.assert_allclose(svd.covariance, P, rtol=0, atol=1e-9 * np.abs(P).max())


@pytest.fixture(scope="module", params=["seed000-sim", "open-sky"])
def scenario_world(request):
    return request.param, generate_world(get_scenario(request.param), list(range(100, 100 + N_EPISODES)))


@pytest.mark.parametrize("method", ["kf", "svd-kf"])
def test_onestep_rmse_within_3_percent_of_per_sample(scenario_world, method):
    name, world = scenario_world
    ref = run_episodes(world, method)
    one = run_episodes(world, method + "+onestep")
    assert not ref.diverged.any() and not one.diverged.any()
    rmse = lambda log: np.sqrt(np.mean(log.horizontal_error ** 2))  # noqa: E731
    rel = rmse(one) / rmse(ref) - 1.0
    assert abs(rel) < 0.03, f"{name} {method}: one-step RMSE {rmse(one):.4f} m vs {rmse(ref):.4f} m ({100 * rel:+.2f}%)"
    # the suffix changed the propagation (an ignored '+onestep' would give identical estimates)
    assert np.abs(one.pos_err_ned - ref.pos_err_ned).max() > 1e-6
