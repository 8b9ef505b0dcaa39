"""The fused fast path (``NavigatorConfig(fused_update=True)``, issue 11) against the numpy recursion it fuses.

* :func:`nav_filters.forms.kf.fused_update` (time update + Joseph update in one compiled kernel, masked rows
  left out) equals ``KalmanFilter.predict`` followed by the prepared numpy update ``_update_reference``:
  float64 to round-off, float32 to its precision, in its three modes (no time update; ``D Phi P Phi^T D + Q``
  with per-state fading; from a given prior), with masked rows holding garbage, batch rows without any
  measurement, a correlated R, serial and parallel kernels; a row whose S is not positive definite raises
  and nothing is committed;
* the adaptive laws that compose ``kf`` (``sage-husa``, ``stkf``, ``ma-stkf``) give the same episodes with the
  fused path as without (same equations, different rounding), and the per-satellite R law's parallel kernel
  gives the serial kernel's bits;
* the option is plumbed (navigator config, env kwarg, failure isolation) and off by default.
"""
import numpy as np
import pytest

from envs.episodes import navigator_for, run_episodes
from envs.sim.world import generate_world
from nav_filters.error_model import N_STATES
from nav_filters.forms import KalmanFilter, SvdKalmanFilter
from nav_filters.forms.base import prepare_measurement, symmetrize
from nav_filters.forms.kf import PARALLEL_MIN_BATCH, fused_update, transition_prior
from nav_filters.navigator import NavigatorConfig

N = 17
TOL = {np.float64: dict(rtol=1e-10, atol=1e-10), np.float32: dict(rtol=2e-3, atol=2e-3)}


def _problem(B, m=12, seed=0, correlated=False):
    """A batch shaped like the navigator's: GNSS-like sparse H rows (position + clock, velocity + drift),
    random masks (row 0: no valid measurement at all), masked rows holding non-neutral garbage."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(B, N, N))
    P = A @ A.mT / N + np.eye(N)
    H = np.zeros((B, m, N))
    for i in range(m):
        cols = [6, 7, 8, 15] if i % 2 == 0 else [3, 4, 5, 16]
        H[:, i, cols] = rng.normal(size=(B, 4))
    dz = rng.normal(size=(B, m))
    R = np.zeros((B, m, m))
    idx = np.arange(m)
    R[:, idx, idx] = rng.uniform(0.5, 2.0, (B, m))
    if correlated:  # correlated pairs of rows
        R[:, idx[0::2], idx[1::2]] = R[:, idx[1::2], idx[0::2]] = 0.3
    mask = rng.random((B, m)) < 0.7
    mask[0] = False
    Phi = np.eye(N) + 0.05 * rng.normal(size=(B, N, N))
    Q = 0.01 * (np.eye(N) + 0.1 * np.ones((N, N)))
    Q = np.broadcast_to(Q, (B, N, N)).copy()
    x = rng.normal(size=(B, N))
    fade = rng.uniform(1.0, 3.0, (B, N))
    return P, x, H, R, dz, mask, Phi, Q, fade


def _reference(P, x, H, R, dz, mask, dtype, Phi=None, Q=None, fade=None):
    kf = KalmanFilter(P, x0=x, dtype=dtype)
    if Phi is not None:
        s = np.sqrt(fade if fade is not None else np.ones(x.shape))[:, :, None]
        kf.predict(s * Phi, Q)
    res = kf._update_reference(*prepare_measurement(dz, H, R, mask, dtype))
    return kf, res


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("B", [5, PARALLEL_MIN_BATCH])
@pytest.mark.parametrize("mode", ["update", "predict", "prior"])
@pytest.mark.parametrize("correlated", [False, True])
def test_fused_kernel_equals_the_numpy_recursion(dtype, B, mode, correlated):
    P, x, H, R, dz, mask, Phi, Q, fade = _problem(B, correlated=correlated)
    # masked rows hold garbage the kernel must leave out (the reference neutralizes them)
    H[~mask] = 7.0
    dz[~mask] = 1e3
    c = lambda a: np.asarray(a, dtype)  # noqa: E731
    kw = {}
    if mode != "update":
        kw = dict(Phi=c(Phi), Q=c(Q), fade=fade)
        if mode == "prior":
            kw["prior"] = c(0.5 * ((Phi @ P @ Phi.mT) + (Phi @ P @ Phi.mT).mT))
    ref, res = _reference(P, x, H, R, dz, mask, dtype, *( (Phi, Q, fade) if mode != "update" else ()))
    Pn, xn, r, Sd, nis = fused_update(c(P), c(x), c(H), c(R), c(dz), mask, **kw)
    for a in (Pn, xn, r, Sd, nis):
        assert a.dtype == dtype
    tol = TOL[dtype]
    scale = np.abs(ref.P).max()
    np.testing.assert_allclose(Pn / scale, ref.P / scale, **tol)
    np.testing.assert_array_equal(Pn, Pn.mT)  # exactly symmetric
    np.testing.assert_allclose(xn, ref.x, **tol)
    np.testing.assert_allclose(r, res.innovation, **tol)
    np.testing.assert_allclose(Sd, res.innovation_var, **tol)
    np.testing.assert_allclose(nis, res.nis, **{**tol, "atol": tol["atol"] * 10})
    # row 0 has no measurement: the prediction itself
    np.testing.assert_array_equal(r[0], 0.0)
    np.testing.assert_array_equal(Sd[0], 1.0)
    assert nis[0] == 0


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("B", [3, PARALLEL_MIN_BATCH + 5])
def test_transition_prior_equals_numpy(dtype, B):
    """``transition_prior`` (the adaptive laws' prior ``sym(Phi P Phi^T)``, compiled over Phi's non-zeros) equals
    the numpy product to round-off, exactly symmetric, in the dtype of P; a sparse transition (60% zeros, which it
    skips) and a dense one; the serial and parallel kernels."""
    P, _, _, _, _, _, Phi, _, _ = _problem(B)
    Phi_sparse = Phi * (np.random.default_rng(1).random((B, N, N)) < 0.4)
    for T in (Phi, Phi_sparse):
        P_, T_ = P.astype(dtype), T.astype(dtype)
        out = transition_prior(T, P_)  # Phi given in float64: cast to P's dtype
        assert out.dtype == dtype and out.shape == (B, N, N)
        np.testing.assert_array_equal(out, out.mT)
        np.testing.assert_allclose(out, symmetrize(T_ @ P_ @ T_.mT), **TOL[dtype])
    with pytest.raises(AssertionError):  # the check can see a wrong transition: Phi^T in place of Phi
        np.testing.assert_allclose(transition_prior(Phi.mT, P), symmetrize(Phi @ P @ Phi.mT), **TOL[np.float64])


def test_kalman_filter_fused_methods_agree_with_the_plain_form():
    """``set_fused`` switches kf's update and predicted_update to the kernel; the results agree with the plain
    form's; the SVD forms have one too (issue 37: tests/nav_filters/test_svd_fused.py)."""
    P, x, H, R, dz, mask, Phi, Q, fade = _problem(70, seed=3)
    Rd = np.diagonal(R, axis1=1, axis2=2)
    plain, fused = KalmanFilter(P, x0=x), KalmanFilter(P, x0=x)
    assert fused.set_fused(True) and not plain.fused
    for f in (plain, fused):
        f.predict(Phi, Q)
        f.update(dz, H, Rd, mask)
        f.predicted_update(Phi, Q, dz, H, Rd, mask, fade=fade)
    np.testing.assert_allclose(fused.P, plain.P, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fused.x, plain.x, rtol=1e-10, atol=1e-12)
    svd = SvdKalmanFilter(P)
    assert svd.set_fused(True) is True and svd.fused is True
    from nav_filters.registry import make_form
    akf = make_form("svd-akf", P)  # the law's own fast kernels on, and its SVD inner form's
    assert akf.set_fused(True) is True and akf.fused and akf.inner.fused


def test_not_positive_definite_row_raises_and_commits_nothing():
    P, x, H, R, dz, mask, Phi, Q, fade = _problem(6, seed=1)
    mask[2] = True
    P[2] = -1e6 * np.eye(N)
    kf = KalmanFilter(np.abs(P) + np.eye(N) * 0, x0=x)
    kf.set_fused(True)
    kf.P = P.copy()
    before = kf.P.copy(), kf.x.copy()
    with pytest.raises(np.linalg.LinAlgError):
        kf.predicted_update(np.broadcast_to(np.eye(N), P.shape), np.zeros_like(P), dz, H,
                            np.diagonal(R, axis1=1, axis2=2), mask)
    np.testing.assert_array_equal(kf.P, before[0])
    np.testing.assert_array_equal(kf.x, before[1])


@pytest.mark.parametrize("method", ["sage-husa", "stkf", "ma-stkf", "svd-akf"])
def test_adaptive_laws_give_the_same_episodes_fused(method):
    """Paired episodes (seed 000 drive, two turns, averaged transition): the fused path's position errors equal
    the unfused ones to well below a millimetre (same equations; rounding differs), and it is really on."""
    w = generate_world("seed000-sim", [0, 1])
    base = run_episodes(w, method, exact_transition=False)
    fast = run_episodes(w, method, exact_transition=False, fused_update=True)
    assert not fast.diverged.any()
    np.testing.assert_allclose(fast.pos_err_ned, base.pos_err_ned, rtol=0, atol=1e-4)
    np.testing.assert_allclose(fast.nis, base.nis, rtol=1e-5, atol=1e-8)
    nav = navigator_for(w, method, exact_transition=False, fused_update=True)
    assert nav.form.fused and nav.form.inner.fused


def test_satellite_r_parallel_kernel_gives_the_serial_bits(monkeypatch):
    """The per-satellite R law (sage-husa's registered default) runs its serial kernel on row chunks in
    parallel on the fused path (B >= 64): every output equals the serial kernel's bit for bit."""
    import nav_filters.adaptive.satellite_r as sr
    from nav_filters.adaptive.base import EpochContext
    from nav_filters.kernels import PARALLEL_MIN_BATCH
    from nav_filters.registry import make_form

    B, m = PARALLEL_MIN_BATCH + 6, 24
    rng = np.random.default_rng(0)
    A = rng.normal(size=(B, N, N))
    law = make_form("sage-husa", A @ A.mT + np.eye(N))
    assert law.config.r_mode == "satellite"
    K = law._sat_scale.shape[1]
    law._sat_scale[:] = rng.uniform(1, 5, (B, K))  # a history: scales, counts, last epochs (aging, forgetting)
    law._sat_count[:] = rng.integers(0, 20, (B, K))
    law._sat_last[:] = rng.integers(-1, 3, (B, K))
    law._epoch[:] = 3
    r = rng.normal(size=(B, m))
    H = np.zeros((B, m, N))
    H[:, :m // 2, 6:9] = rng.normal(size=(B, m // 2, 3))
    H[:, :m // 2, 15] = 1.0
    H[:, m // 2:, 3:6] = rng.normal(size=(B, m // 2, 3))
    H[:, m // 2:, 16] = 1.0
    R = np.zeros((B, m, m))
    R[:, np.arange(m), np.arange(m)] = rng.uniform(1, 9, (B, m))
    mask = rng.random((B, m)) < 0.8
    sats = np.tile(np.arange(m // 2), (B, 2)) + np.where(np.arange(m) < m // 2, 0, K // 2)
    law._keys = np.where(mask, sats, -1)
    ctx = EpochContext(pending=True, Phi=None, Q=0.01 * np.broadcast_to(np.eye(N), (B, N, N)).copy(),
                       prior=A @ A.mT)
    d, active = np.full(B, 0.1), rng.random(B) < 0.9
    calls = []
    orig = sr._r_sat_parallel
    monkeypatch.setattr(sr, "_r_sat_parallel", lambda *a: (calls.append(1), orig(*a))[1])
    plans = []
    for fused in (False, True):
        law.fused = fused
        plans.append(law._plan_satellite(r, H, R, mask, ctx, d, active, {}))
    assert len(calls) == 1
    np.testing.assert_array_equal(plans[0].R, plans[1].R)
    np.testing.assert_array_equal(plans[0].pending["r_scale"], plans[1].pending["r_scale"])
    for a, b in zip(plans[0].pending["sat"], plans[1].pending["sat"]):
        np.testing.assert_array_equal(a, b)
    assert (plans[0].pending["sat"][1] > 0).any()  # some satellites were updated


@pytest.mark.parametrize("method", ["kf", "sage-husa", "stkf"])
def test_failure_isolation_on_the_fused_path(method):
    """A row whose update fails is flagged and parked; the others end bit for bit where a clean fused run
    ends (the kernel commits nothing when it raises; rows are independent)."""
    from tests.nav_filters.test_failure_isolation import _run, _set_inner_P
    from nav_filters.navigator import REASON_UPDATE

    w = generate_world("seed000-sim", [0, 1, 2])
    kw = dict(exact_transition=False, fused_update=True)
    clean = _run(navigator_for(w, method, **kw), w, 8)

    def poison(nav):
        nav.flush_prediction()
        _set_inner_P(nav, 1, -1e6 * np.eye(N_STATES))

    nav = _run(navigator_for(w, method, **kw), w, 8, poison)
    assert nav.divergence_code.tolist() == [0, REASON_UPDATE, 0]
    for name in ("r", "v", "C", "clk", "drift"):
        np.testing.assert_array_equal(getattr(nav, name)[[0, 2]], getattr(clean, name)[[0, 2]], err_msg=name)
    np.testing.assert_array_equal(nav.covariance[[0, 2]], clean.covariance[[0, 2]])


def test_option_is_plumbed_off_for_the_navigator_and_on_for_the_envs():
    import gymnasium as gym
    import envs  # noqa: F401
    from envs.episodes import process_noise_for

    w = generate_world("seed000-sim", [0])
    with pytest.raises(ValueError, match="fused_update"):
        NavigatorConfig(noise=process_noise_for(w), fused_update="yes")
    assert navigator_for(w, "sage-husa").form.fused is False
    env = gym.make("GnssIns/SageHusa-v1", scenario="noise-burst", episode_length_s=10.0)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    nav = env.unwrapped.core.nav
    assert nav.config.fused_update and nav.form.fused and nav.form.inner.fused  # the env default (issue 11)
    vec = gym.make_vec("GnssIns/SageHusa-v1", num_envs=2, vectorization_mode="vector_entry_point",
                       scenario="noise-burst", episode_length_s=10.0, fused_update=False)
    vec.reset(seed=0)
    assert vec.core.nav.form.fused is False
    with pytest.raises(ValueError, match="fused_update"):
        gym.make("GnssIns/SageHusa-v1", fused_update=1)


def test_own_symmetric_eigendecomposition():
    """``sym_eig_inplace`` (Householder + implicit QR, the Sage-Husa Q law's projection on the fused path):
    ``A = Vt^T diag(d) Vt`` and ``Vt`` orthonormal to round-off, eigenvalues those of ``np.linalg.eigvalsh``,
    on random matrices, spectra spread over ten decades like the law's (W Q W with P >> Q), and the edge
    cases: diagonal, identity (a full cluster), zero, a 1e-300 coupling, a 1 x 1 and a 2 x 2 matrix; the rows
    padded with zero columns, which stay zero."""
    import numba as nb
    from nav_filters.kernels import padded_width, sym_eig_inplace

    @nb.njit
    def run(As, ds, Vs):
        ok = True
        n = As.shape[1]
        W = padded_width(n)
        A = np.zeros((n, W))   # rows padded with zero columns, one scratch for every matrix (as the Q law)
        Vt = np.zeros((n, W))
        for b in range(As.shape[0]):
            A[:, :n] = As[b]
            ok &= sym_eig_inplace(A, ds[b], Vt, np.empty(n), np.empty(W), np.empty(W))
            ok &= np.all(A[:, n:] == 0) and np.all(Vt[:, n:] == 0)   # the padding stays zero
            Vs[b] = Vt[:, :n]
        return ok

    rng = np.random.default_rng(4)
    cases = []
    M = rng.normal(size=(40, N, N))
    cases.append(M + M.mT)
    Qo, _ = np.linalg.qr(rng.normal(size=(40, N, N)))
    cases.append(Qo @ np.diag(np.logspace(-4, 6, N) * rng.choice([-1, 1], N)) @ Qo.mT)
    edge = np.zeros((4, N, N))
    edge[0] = np.diag(rng.normal(size=N))
    edge[1] = np.eye(N)
    edge[3] = np.eye(N)
    edge[3, 0, 1] = edge[3, 1, 0] = 1e-300
    cases.append(edge)
    cases.append(np.array([[[3.0]]]))
    cases.append(np.array([[[2.0, 1.0], [1.0, -2.0]]]))
    for A in cases:
        B, n, _ = A.shape
        d, Vt = np.empty((B, n)), np.empty((B, n, n))
        assert run(A, d, Vt)
        scale = np.maximum(np.abs(A).max((1, 2)), 1e-300)[:, None, None]
        rec = np.einsum("bki,bk,bkj->bij", Vt, d, Vt)
        assert np.abs((rec - A) / scale).max() < 1e-13
        assert np.abs(Vt @ Vt.mT - np.eye(n)).max() < 1e-13
        np.testing.assert_allclose(np.sort(d, 1) / scale[:, :, 0], np.linalg.eigvalsh(A) / scale[:, :, 0],
                                   rtol=0, atol=1e-13)


def test_serial_and_parallel_kernels_have_their_own_cache_entries():
    """numba's cache keys an entry by function name and bytecode, not by ``parallel``: each serial/parallel pair
    of row kernels must be two functions with distinct cache files (else one process's parallel build is
    loaded for the serial dispatcher: a thread-pool launch per single-row call), with the flags they claim,
    and the two give the same bits on the same rows."""
    from nav_filters import averaged_transition, kernels
    from nav_filters.adaptive import sage_husa, satellite_r
    from nav_filters.forms import kf

    pairs = [(kernels._serial, kernels._parallel), (averaged_transition._serial, averaged_transition._parallel),
             (kf._joseph_serial, kf._joseph_parallel), (kf._fused_serial, kf._fused_parallel),
             (sage_husa._adapt_q_serial, sage_husa._adapt_q_parallel),
             (satellite_r._commit_serial, satellite_r._commit_parallel), (kf._prior_serial, kf._prior_parallel)]
    names = set()
    for ser, par in pairs:
        assert ser.targetoptions["parallel"] is False and par.targetoptions["parallel"] is True
        assert ser.py_func.__code__ is par.py_func.__code__  # one implementation
        names |= {ser._cache._cache_file._index_name, par._cache._cache_file._index_name}
    assert len(names) == 2 * len(pairs)
    P, x, H, R, dz, mask, Phi, Q, fade = _problem(PARALLEL_MIN_BATCH + 3, seed=5)
    outs = []
    for kern, nchunk in ((kf._fused_serial, 1), (kf._fused_parallel, 7)):
        B, m, n = H.shape
        o = [np.empty((B, n, n)), np.empty((B, n)), np.empty((B, m)), np.empty((B, m)), np.zeros(B), np.empty(B, bool)]
        kern(P, x, Phi, np.sqrt(fade), Q, P, 1, H, R, dz, mask, *o, nchunk)
        outs.append(o)
    for a, b in zip(*outs):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("B", [9, PARALLEL_MIN_BATCH + 6])  # the serial and the parallel kernel
def test_satellite_summary_kernel_equals_numpy(B):
    """The commit of sage-husa's per-satellite tables (scale, count, last epoch per key: one compiled call on the
    fused path) and the summary of its adaptive state (max, median, risen count, count over the used pseudorange
    rows): the same values as the numpy lines, bit for bit, also where a row holds one key twice (last wins)."""
    from nav_filters.adaptive.satellite_r import ROSE_FACTOR
    from nav_filters.registry import make_form

    rng = np.random.default_rng(2)
    m = 10
    laws = [make_form("sage-husa", np.broadcast_to(np.eye(N), (B, N, N)).copy()) for _ in range(2)]
    laws[1].set_fused(True)
    K = laws[0]._sat_scale.shape[1]
    mask = rng.random((B, m)) < 0.7
    mask[0] = False
    keys = np.where(rng.random((B, m)) < 0.8, rng.integers(0, K, (B, m)), -1)
    s_rows = rng.uniform(0.5, 9, (B, m))
    s_rows[1, :4] = 2.0  # ties
    s_prev = s_rows / rng.choice([1.0, ROSE_FACTOR + 1], (B, m))
    n_rows = rng.integers(0, 5, (B, m))
    mask[2, [3, 5]] = True
    keys[2, [3, 5]] = 7  # one key twice in a row
    epoch = np.arange(B) + 4
    for law in laws:
        law._commit_satellites(mask, keys, s_rows, n_rows, s_prev, epoch)
    for name in ("_sat_summary", "_sat_scale", "_sat_count", "_sat_last", "_epoch"):
        np.testing.assert_array_equal(getattr(laws[1], name), getattr(laws[0], name), err_msg=name)
    assert laws[0]._sat_scale[2, 7] == s_rows[2, 5] and laws[0]._sat_last[2, 7] == 6
    assert (laws[0]._sat_last >= 0).sum() > B  # the tables were written
    assert laws[0]._sat_summary[:, 2].any() and laws[0]._sat_summary[0].tolist() == [1.0, 1.0, 0.0, 0.0]


def test_strong_tracking_fast_fit_split_agrees():
    """The strong-tracking laws' fit split on the fused path: the compiled sparse ``diag(H X H^T)`` and the whole
    split equal the numpy ones to round-off."""
    from nav_filters.adaptive.innovation import fit_split, quadratic_diag

    P, x, H, R, dz, mask, Phi, Q, fade = _problem(11, m=16, seed=7)
    d, Hp, Rp, mk = prepare_measurement(dz, H, R, mask, np.float64)
    prior = 0.5 * (P + P.mT)
    np.testing.assert_allclose(quadratic_diag(Hp, prior, fast=True), quadratic_diag(Hp, prior), rtol=1e-12, atol=1e-12)
    s0, s1 = fit_split(d, Hp, Rp, mk, prior, Q), fit_split(d, Hp, Rp, mk, prior, Q, fast=True)
    for name in ("e_fit", "e_res", "dof", "p", "tr_m", "tr_q", "n"):
        np.testing.assert_allclose(getattr(s1, name), getattr(s0, name), rtol=1e-12, atol=1e-12, err_msg=name)
    assert (s0.dof > 0).any()


@pytest.mark.parametrize("n_types", [1, 2, 3])
def test_split_fading_kernel_equals_numpy(n_types):
    """The strong-tracking laws' fading from the snapshot split (smoothed statistics, lower confidence bound,
    noise gate, the printed law's factor where no type has redundancy) is compiled on the fused path: the same
    values bit for bit as the numpy lines, over rows with and without redundancy, scalar and per-row scales."""
    from nav_filters.adaptive.innovation import FitSplit
    from nav_filters.adaptive.strong_tracking import SPLIT_STATS, split_fading

    seen = np.zeros(3, bool)
    for seed in range(6):
        rng = np.random.default_rng(seed)
        B, T = 40, n_types
        dof = np.where(rng.random((B, T)) < 0.6, rng.integers(0, 6, (B, T)), 0).astype(float)
        p = np.where(dof > 0, rng.integers(1, 5, (B, T)), np.where(rng.random((B, T)) < 0.5, 0, 2)).astype(float)
        split = FitSplit(e_fit=rng.gamma(2, 3, (B, T)), e_res=rng.gamma(2, 3, (B, T)) * (dof > 0), dof=dof, p=p,
                         tr_m=rng.gamma(1, 1e-2 if seed % 2 else 10, (B, T)), tr_q=rng.gamma(1, 0.1, (B, T)),
                         n=rng.integers(0, 3, (B, T)), n_other=rng.integers(0, 2, B) * (rng.random(B) < 0.3))
        prev = rng.normal(0, 5, (B, SPLIT_STATS))
        prev[:5] = 0.0
        args = (split, prev, rng.uniform(0.05, 1, B), rng.uniform(0.5, 2, B), 2.0, 50.0,
                3.0 if seed % 4 else np.inf, rng.uniform(1, 4, B))
        scale = rng.uniform(0.5, 3, B) if seed % 3 else 1.0
        ref = split_fading(*args, scale=scale)
        fast = split_fading(*args, scale=scale, fast=True)
        for a, b in zip(ref, fast):
            np.testing.assert_array_equal(b, a)
        lam = ref[0]
        seen |= [(lam > 1).any(), (lam == 1).any(), (lam == args[-1]).any()]
    assert seen.all()  # rows that fade, that hold, that take the printed law's factor
