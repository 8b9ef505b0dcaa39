"""The averaged-dynamics transition (``NavigatorConfig(exact_transition=False)``) against its references.

* the compiled series equals the numpy specification (float64, batched, serial and parallel kernels);
* constant F: the series equals ``expm(F T)`` and Van Loan's integral to round-off (float64; float32 to its
  own precision), and the default per-sample composition ``(I + F h)^n`` converges to it at first order in
  ``h`` (the only difference left is the default's Euler step: O(h / T) relative);
* varying F (a real urban drive, turning): what the navigator hands to ``predict`` equals the series of the
  summed F and Q of the numpy reference loop, and differs from the exact per-sample composition by no more
  than the Euler-step term plus the neglected commutator (second Magnus) term, both computed here;
* the option is plumbed (navigator config, env kwarg), ignored nowhere, and an episode's RMSE stays within
  1% of the default's on paired episodes.
"""
import math

import numpy as np
import pytest
from scipy.linalg import expm

from envs.episodes import navigator_for, process_noise_for, run_episodes
from envs.metrics import paired_difference, summarize
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world
from nav_filters.averaged_transition import SERIES_ORDER, averaged_transition, averaged_transition_into
from nav_filters.error_model import system_matrix
from nav_filters.ins import mechanize
from nav_filters.kernels import F_NONZERO
from nav_filters.navigator import NavigatorConfig

N = 17


@pytest.fixture(scope="module")
def urban():
    return generate_world(get_scenario("urban", duration_s=30.0), [3, 4])


def _F(world, k=5):
    noise = process_noise_for(world)
    i = world.init
    return system_matrix(i.C_eb, world.imu.f_b[:, k], i.r_e, noise.gyro_bias_tau_s, noise.accel_bias_tau_s), noise


def _Qc(noise, C):
    """(B, 17, 17) G Q_c G^T with the body-frame IMU blocks rotated by C (B, 3, 3)."""
    q = noise.diagonal()
    Qc = np.zeros(C.shape[:1] + (N, N))
    Qc[:, np.arange(N), np.arange(N)] = q
    Qc[:, 0:3, 0:3] = C @ np.diag(q[0:3]) @ C.mT
    Qc[:, 3:6, 3:6] = C @ np.diag(q[3:6]) @ C.mT
    return Qc


def _van_loan(F, Qc, T):
    """expm(F T) and int_0^T e^{Fs} Qc e^{F^T s} ds by Van Loan's block exponential (one row)."""
    Z = np.zeros((2 * N, 2 * N))
    Z[:N, :N], Z[:N, N:], Z[N:, N:] = -F, Qc, F.T
    E = expm(Z * T)
    Phi = E[N:, N:].T
    Q = Phi @ E[:N, N:]
    return Phi, 0.5 * (Q + Q.T)


def _corr_err(Q, Qref):
    """max |Q - Qref| / sqrt(Qref_ii Qref_jj): an error relative to each entry's natural scale."""
    d = np.sqrt(np.maximum(np.diagonal(Qref, axis1=-2, axis2=-1), 1e-300))  # a zero variance: diff must be 0
    return float(np.max(np.abs(Q - Qref) / (d[..., :, None] * d[..., None, :])))


@pytest.mark.parametrize("B", [2, 70])  # serial and parallel kernels
def test_compiled_series_matches_numpy_specification(B):
    rng = np.random.default_rng(0)
    A = np.zeros((B, N, N))
    A[:, F_NONZERO[:, 0], F_NONZERO[:, 1]] = rng.normal(0, 1, (B, len(F_NONZERO)))
    X = rng.normal(size=(B, N, N))
    S = X @ X.mT * 1e-3
    Phi, Q = np.empty((B, N, N)), np.empty((B, N, N))
    averaged_transition_into(A, S, Phi, Q)
    Phi_ref, Q_ref = averaged_transition(A, S)
    np.testing.assert_allclose(Phi, Phi_ref, rtol=1e-12, atol=1e-12 * np.abs(Phi_ref).max())
    np.testing.assert_allclose(Q, Q_ref, rtol=1e-12, atol=1e-12 * np.abs(Q_ref).max())
    np.testing.assert_array_equal(Q, Q.mT)  # exactly symmetric
    # order 1: the first-order terms only
    averaged_transition_into(A, S, Phi, Q, order=1)
    np.testing.assert_allclose(Phi, np.eye(N) + A, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(Q, S + 0.5 * (A @ S + S @ A.mT), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("T", [1.0, 3.0])
@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 2e-5)])
def test_constant_F_equals_expm_and_van_loan(urban, T, dtype, tol):
    F, noise = _F(urban)
    Qc = _Qc(noise, urban.init.C_eb)
    Phi, Q = averaged_transition((F * T).astype(dtype), (Qc * T).astype(dtype))
    assert Phi.dtype == Q.dtype == dtype and Phi.shape == (2, N, N)
    for b in range(2):
        Pe, Qe = _van_loan(F[b], Qc[b], T)
        assert np.abs(Phi[b] - Pe).max() < tol * np.abs(Pe).max()
        assert _corr_err(Q[b], Qe) < (1e-9 if dtype == np.float64 else 1e-3)
    # the order is what makes it exact: order 2 drops the position <- gyro-bias block ([a x] C T^3 / 6)
    P2, _ = averaged_transition(F * T, Qc * T, order=2)
    Pe, _ = _van_loan(F[0], Qc[0], T)
    assert np.abs(P2[0, 6:9, 9:12] - Pe[6:9, 9:12]).max() > 0.5 * np.abs(Pe[6:9, 9:12]).max()
    assert SERIES_ORDER >= 6


def test_per_sample_composition_converges_to_it_at_first_order(urban):
    """Constant F: (I + F h)^n and the exactly composed per-sample Q approach the series as h -> 0, the
    difference halving with h (the default's Euler step is what separates them)."""
    F, noise = _F(urban)
    F, Qc = F[0], _Qc(noise, urban.init.C_eb)[0]
    T = 1.0
    Phi, Q = averaged_transition((F * T)[None], (Qc * T)[None])
    errs = []
    for n in (100, 200, 400):
        h = T / n
        A = np.eye(N) + F * h
        P, Qn = np.eye(N), np.zeros((N, N))
        for _ in range(n):
            P, Qn = A @ P, A @ Qn @ A.T + Qc * h
        errs.append((np.abs(P - Phi[0]).max() / np.abs(Phi[0]).max(), _corr_err(Qn, Q[0])))
    e = np.array(errs)
    assert e[0, 0] < 0.02 and e[0, 1] < 0.03       # at 100 Hz: within a few percent, O(1 / n)
    ratios = e[:-1] / e[1:]
    assert np.all((ratios > 1.8) & (ratios < 2.2)), ratios


def _reference_epoch(world, n, start=1):
    """Numpy reference loop over n IMU samples: per-sample F_i, Q_i, the exact composition and the sums."""
    noise = process_noise_for(world)
    i = world.init
    r, v, C = i.r_e.copy(), i.v_e.copy(), i.C_eb.copy()
    B, h = r.shape[0], 1.0 / world.scenario.imu_rate_hz
    Phi, Q = np.broadcast_to(np.eye(N), (B, N, N)).copy(), np.zeros((B, N, N))
    A, S, Fs = np.zeros((B, N, N)), np.zeros((B, N, N)), []
    f, w = world.imu.f_b[:, start:start + n], world.imu.w_b[:, start:start + n]
    for k in range(n):
        Fk = system_matrix(C, f[:, k], r, noise.gyro_bias_tau_s, noise.accel_bias_tau_s)
        Qk = _Qc(noise, C) * h
        Phi = (np.eye(N) + Fk * h) @ Phi
        Q = (np.eye(N) + Fk * h) @ Q @ (np.eye(N) + Fk * h).mT + Qk
        A += Fk * h
        S += Qk
        Fs.append(Fk * h)
        r, v, C = mechanize(r, v, C, f[:, k], w[:, k], h)
    return dict(Phi=Phi, Q=Q, A=A, S=S, Fh=np.stack(Fs, 1), f=f, w=w, h=h)


from test_onestep import _spy  # noqa: E402  (records the (Phi, Q) handed to the form's predict)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_navigator_hands_the_series_of_the_integrated_dynamics(urban, dtype):
    """Varying F over a turning 1 s epoch: the navigator's (Phi, Q) is the series of sum F_i h and sum Q_i
    (numpy reference loop), its mechanization is the default's, and it stays within the bound derived from
    what is neglected: the Euler-step term (constant-F difference) plus the second Magnus term."""
    n = 100
    ref = _reference_epoch(urban, n, start=1501)
    fast, exact = (navigator_for(urban, "kf", dtype, exact_transition=e) for e in (False, True))
    i = urban.init
    for nav in (fast, exact):  # start both at the reference loop's initial state (the world's truth start)
        nav.r[:], nav.v[:], nav.C[:] = i.r_e, i.v_e, i.C_eb
    calls = _spy(fast)
    fast.propagate_epoch(ref["f"], ref["w"], ref["h"])
    exact.propagate_epoch(ref["f"], ref["w"], ref["h"])
    for name in ("r", "v", "C", "clk"):  # the mechanization does not depend on the option
        np.testing.assert_array_equal(getattr(fast, name), getattr(exact, name))
    fast.flush_prediction()
    Phi, Q = calls[0]
    Phi_s, Q_s = averaged_transition(ref["A"], ref["S"])
    rtol = 1e-10 if dtype == "float64" else 1e-6
    np.testing.assert_allclose(Phi, Phi_s, rtol=rtol, atol=rtol * np.abs(Phi_s).max())
    assert _corr_err(Q, Q_s) < rtol
    # bound against the exact composition: Euler term (constant F, measured as above with the mean F) plus
    # the neglected commutator: exp(A) vs the time-ordered product exp(A + Omega_2 + ...)
    Fh = ref["Fh"]
    for b in range(2):
        Fbar = ref["A"][b]
        euler = np.linalg.matrix_power(np.eye(N) + Fbar / n, n)
        omega2 = np.zeros((N, N))
        csum = np.zeros((N, N))
        for k in range(n):  # 1/2 sum_{k > j} [F_k h, F_j h]
            omega2 += 0.5 * (Fh[b, k] @ csum - csum @ Fh[b, k])
            csum += Fh[b, k]
        # Euler part (as for constant F) + the effect of the second Magnus term (exp(A + Omega_2) - exp(A)),
        # which predicts the time-variation error to ~1e-4 here; 10% margin for the higher Magnus terms
        magnus = np.abs(expm(Fbar + omega2) - expm(Fbar)).max()
        bound = np.abs(euler - expm(Fbar)).max() + 1.1 * magnus
        err = np.abs(Phi[b] - ref["Phi"][b]).max()
        assert err <= bound, (err, bound)
        assert err > 1e-6  # the two modes really differ
        assert _corr_err(Q[b], ref["Q"][b]) < 0.03


def test_onestep_with_averaged_transition_sums_the_noise(urban):
    ref = _reference_epoch(urban, 50)
    nav = navigator_for(urban, "kf+onestep", exact_transition=False)
    i = urban.init
    nav.r[:], nav.v[:], nav.C[:] = i.r_e, i.v_e, i.C_eb
    calls = _spy(nav)
    nav.propagate_epoch(ref["f"], ref["w"], ref["h"])
    nav.flush_prediction()
    Phi, Q = calls[0]
    np.testing.assert_allclose(Phi, averaged_transition(ref["A"], ref["S"])[0], rtol=1e-10, atol=1e-12)
    assert _corr_err(Q, ref["S"]) < 1e-10


def test_split_epoch_accumulates_like_one_call(urban):
    """Pending samples fed in pieces (propagate per sample, or two calls) integrate to the same F and Q."""
    ref = _reference_epoch(urban, 20)
    navs = [navigator_for(urban, "kf", exact_transition=False) for _ in range(2)]
    spies = [_spy(nav) for nav in navs]
    navs[0].propagate_epoch(ref["f"], ref["w"], ref["h"])
    navs[1].propagate_epoch(ref["f"][:, :7], ref["w"][:, :7], ref["h"])
    for k in range(7, 20):
        navs[1].propagate(ref["f"][:, k], ref["w"][:, k], ref["h"])
    for nav in navs:
        nav.flush_prediction()
        nav.flush_prediction()  # nothing pending: no second predict
    assert len(spies[0]) == len(spies[1]) == 1
    np.testing.assert_allclose(spies[1][0][0], spies[0][0][0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(spies[1][0][1], spies[0][0][1], rtol=1e-12, atol=1e-24)


def test_bad_option_names_the_field(urban):
    noise = process_noise_for(urban)
    with pytest.raises(ValueError, match="exact_transition"):
        NavigatorConfig(noise=noise, exact_transition="no")
    with pytest.raises(ValueError, match="order"):
        averaged_transition(np.zeros((1, N, N)), np.zeros((1, N, N)), order=0)
    with pytest.raises(ValueError, match="Qc_int"):
        averaged_transition(np.zeros((1, N, N)), np.zeros((2, N, N)))


def test_env_kwarg_reaches_the_navigator():
    import gymnasium as gym
    import envs  # noqa: F401
    env = gym.make("GnssIns/SageHusa-v1", scenario="noise-burst", episode_length_s=10.0, exact_transition=True)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert env.unwrapped.core.nav.exact_transition is True
    vec = gym.make_vec("GnssIns/SageHusa-v1", num_envs=2, vectorization_mode="vector_entry_point",
                       scenario="noise-burst", episode_length_s=10.0)
    vec.reset(seed=0)
    assert vec.core.nav.exact_transition is False  # the env default: the averaged dynamics (issue 11)
    assert navigator_for(generate_world("seed000-sim", [0]), "kf").exact_transition is True  # eval's default
    with pytest.raises(ValueError, match="exact_transition"):
        gym.make("GnssIns/SageHusa-v1", exact_transition=1)


@pytest.mark.parametrize("method", ["kf", "sage-husa"])
def test_rmse_within_one_percent_of_the_exact_composition(method):
    """Paired episodes (same truth and sensor errors) on the seed 000 drive with its two turns: the horizontal
    RMSE of the averaged dynamics is within 1% of the exact per-sample composition's, and not identical."""
    w = generate_world("seed000-sim", [0, 1, 2, 3])
    exact = run_episodes(w, method)
    fast = run_episodes(w, method, exact_transition=False)
    d = paired_difference(fast, exact)
    assert abs(d["rel_diff"]) < 0.01, d
    assert d["diff_rmse_h_m"] != 0.0
    assert summarize(fast)["diverged"] == 0
    assert math.isfinite(summarize(fast)["mean_nees_pv"])


def test_float32_end_to_end_and_batch_invariance():
    """float32 filter arithmetic with the averaged transition: same RMSE as float64 within 1%; a row of a
    batch is the same episode as that world run alone (the integrals are per row)."""
    w = generate_world("seed000-sim", [5, 6, 7])
    f64 = run_episodes(w, "sage-husa", exact_transition=False)
    f32 = run_episodes(w, "sage-husa", "float32", exact_transition=False)
    assert not f32.diverged.any()
    assert abs(paired_difference(f32, f64)["rel_diff"]) < 0.01
    one = run_episodes(generate_world("seed000-sim", [6]), "sage-husa", exact_transition=False)
    np.testing.assert_allclose(one.pos_err_ned[0], f64.pos_err_ned[1], rtol=0, atol=1e-9)
