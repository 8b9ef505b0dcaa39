"""The robust measurement screens: fault detection and exclusion (``kf-fde``, ``+fde``), IGG-III and Huber
M-estimation (``kf-igg3``, ``kf-huber``) and the variational-Bayes adaptive R (``vb-akf``)."""
import numpy as np
import pytest
from scipy.stats import binom

from nav_filters.adaptive import (FaultExclusion, FdeConfig, RobustConfig, RobustUpdate, VariationalR, VbConfig,
                                  law_factory)
from nav_filters.adaptive.base import EpochContext
from nav_filters.adaptive.fde import fde_screen, fde_screen_reference
from nav_filters.adaptive.mestimation import robust_weights, robust_weights_reference
from nav_filters.adaptive.robust_rows import huber_weight, igg3_weight
from nav_filters.error_model import CLK, DRIFT, N_STATES, POS, VEL
from nav_filters.forms import KalmanFilter
from nav_filters.measurements import measurement_keys
from nav_filters.registry import FORMS, PLAIN_FORMS, make_form

N = N_STATES


def lines_of_sight(rng, B, C):
    """(B, C, 3) unit lines of sight above the horizon."""
    az = rng.uniform(0, 2 * np.pi, (B, C))
    el = rng.uniform(np.radians(15), np.radians(85), (B, C))
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)


def gnss_rows(rng, B, C, rates=False):
    """(B, m, 17) pseudorange rows ``[-u, CLK 1]`` (and rate rows ``[-u, DRIFT 1]``) of the 17-state model."""
    u = lines_of_sight(rng, B, C)
    H = np.zeros((B, C * (1 + rates), N))
    H[:, :C, POS] = -u
    H[:, :C, CLK] = 1.0
    if rates:
        H[:, C:, VEL] = -u
        H[:, C:, DRIFT] = 1.0
    return H


def prior(rng, B, scale=4.0):
    """(B, 17, 17) a random SPD prior covariance of the order of ``scale``."""
    A = rng.normal(size=(B, N, N))
    return scale * (A @ A.mT / N + np.eye(N))


def draw(rng, H, P, R):
    """Innovations of the exact model: ``dz = H x + v`` with ``x ~ N(0, P)``, ``v ~ N(0, diag R)``."""
    L = np.linalg.cholesky(P)
    x = (L @ rng.normal(size=P.shape[:2] + (1,)))[..., 0]
    return (H @ x[..., None])[..., 0] + rng.normal(size=R.shape) * np.sqrt(R)


# ------------------------------------------------------------------------------------------ weight functions
def test_igg3_and_huber_weights_at_the_zone_boundaries():
    k0, k1, c = 1.5, 3.0, 1.345
    for t in (0.0, 1.0, k0, -k0):
        assert igg3_weight(t, k0, k1) == 1.0
    t = 2.0
    assert igg3_weight(t, k0, k1) == pytest.approx(k0 / t * ((k1 - t) / (k1 - k0)) ** 2, rel=1e-15)
    assert igg3_weight(-t, k0, k1) == igg3_weight(t, k0, k1)
    assert igg3_weight(k1, k0, k1) == 0.0  # continuous at k1: the down-weighted zone ends at 0
    assert igg3_weight(k1 + 1e-9, k0, k1) == 0.0 and igg3_weight(50.0, k0, k1) == 0.0
    assert igg3_weight(k0 * (1 + 1e-12), k0, k1) == pytest.approx(1.0, abs=1e-11)  # continuous at k0
    assert huber_weight(c, c) == 1.0 and huber_weight(0.3, c) == 1.0
    assert huber_weight(2 * c, c) == pytest.approx(0.5) and huber_weight(-4 * c, c) == pytest.approx(0.25)


# ------------------------------------------------------------------------------------------ compiled = numpy
@pytest.mark.parametrize("rates", [False, True])
def test_fde_screen_agrees_with_its_numpy_specification(rates):
    rng = np.random.default_rng(1)
    B, C = 40, 9
    H = gnss_rows(rng, B, C, rates)
    m = H.shape[1]
    P = prior(rng, B)
    R = rng.uniform(1, 9, (B, m))
    dz = draw(rng, H, P, R)
    bad = rng.random((B, m)) < 0.2
    dz = dz + np.where(bad, rng.uniform(15, 80, (B, m)), 0.0)
    mask = rng.random((B, m)) > 0.1
    for cfg in (FdeConfig(), FdeConfig(p_gate=0.0), FdeConfig(p_fa=0.05, min_rows=5)):
        got = fde_screen(dz, H, P, R, mask, cfg)
        ref = fde_screen_reference(dz, H, P, R, mask, cfg)
        for a, b in zip(got, ref):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
        assert got[1].sum() > 0  # the outliers were excluded somewhere


@pytest.mark.parametrize("weight", ["igg3", "huber"])
def test_robust_weights_agree_with_their_numpy_specification(weight):
    rng = np.random.default_rng(2)
    B, C = 30, 8
    H = gnss_rows(rng, B, C, rates=True)
    m = H.shape[1]
    P = prior(rng, B)
    R = rng.uniform(1, 9, (B, m))
    dz = draw(rng, H, P, R) + np.where(rng.random((B, m)) < 0.2, rng.uniform(10, 60, (B, m)), 0.0)
    mask = rng.random((B, m)) > 0.1
    cfg = RobustConfig(weight=weight)
    # to 1e-5: a rejected row stays in the fit with its variance times 1e10 (MIN_WEIGHT), which costs the
    # compiled and the numpy fit different digits around 1e-6 of its standardized residual (a wrong weight
    # function or standardization is off by far more)
    for a, b in zip(robust_weights(dz, H, P, R, mask, cfg), robust_weights_reference(dz, H, P, R, mask, cfg)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_vb_plan_agrees_with_its_numpy_specification():
    rng = np.random.default_rng(3)
    B, C, n_ep = 6, 8, 12
    H = gnss_rows(rng, B, C)
    P0 = prior(rng, B)
    law = VariationalR(P0, config=VbConfig(rho=0.9, scale_min=0.2))
    keys = np.broadcast_to(np.arange(C), (B, C)).copy()
    for k in range(n_ep):
        Phi = np.broadcast_to(np.eye(N), (B, N, N))
        law.predict(Phi, 0.01 * np.broadcast_to(np.eye(N), (B, N, N)))
        R = rng.uniform(1, 4, (B, C))
        dz = draw(rng, H, law.covariance, R) + np.where(np.arange(C) == k % C, 30.0, 0.0)
        mask = rng.random((B, C)) > 0.15
        kk = np.where(mask, np.roll(keys, k % 3, axis=1), -1)  # satellites move between channels
        P_inner = law.inner.covariance
        ctx = EpochContext(pending=True, Phi=law._Phi_acc, Q=law._Q_acc, prior=law._Phi_acc @ P_inner @ law._Phi_acc.mT)
        law._keys = kk
        Rf = np.zeros((B, C, C))
        Rf[:, np.arange(C), np.arange(C)] = R
        plan = law._plan(dz, H, Rf, mask, ctx)
        ref = law._vb_reference(dz, H, Rf, mask, ctx)
        law._keys = None
        np.testing.assert_allclose(plan.pending["scale"], ref[0], rtol=1e-9)
        np.testing.assert_allclose(plan.pending["alpha"], ref[1], rtol=1e-12)
        np.testing.assert_allclose(plan.pending["beta"], ref[2], rtol=1e-9)
        law.update(dz, H, R, mask, keys=kk)


# ------------------------------------------------------------------------------------------ fault exclusion
@pytest.mark.parametrize("fused", [False, True])
def test_fde_excludes_one_gross_outlier_and_then_equals_kf_without_it(fused):
    """One pseudorange of eight 200 m off: kf-fde excludes exactly it, and its update equals kf's with that
    satellite masked (float64, 1e-12 relative), on the numpy path and on the fused compiled one (where the
    excluded row reaches the kernel with its values and only the mask leaves it out)."""
    rng = np.random.default_rng(4)
    B, C = 5, 8
    H = gnss_rows(rng, B, C)
    P0 = prior(rng, B)
    R = np.full((B, C), 4.0)
    bad = rng.integers(0, C, B)
    fde, kf = make_form("kf-fde", P0), KalmanFilter(P0)
    fde.set_fused(fused)
    kf.set_fused(fused)
    Phi = np.eye(N) + 0.01 * rng.normal(size=(B, N, N))
    Q = 0.1 * np.broadcast_to(np.eye(N), (B, N, N))
    fde.predict(Phi, Q)
    kf.predict(Phi, Q)
    dz = draw(rng, H, kf.covariance, R)
    dz[np.arange(B), bad] += 200.0
    res = fde.update(dz, H, R)
    np.testing.assert_array_equal(fde.excluded(), np.ones(B, int))
    keep = np.ones((B, C), bool)
    keep[np.arange(B), bad] = False
    ref = kf.update(dz, H, R, keep)
    np.testing.assert_array_equal(res.n_used, ref.n_used)
    np.testing.assert_allclose(fde.covariance, kf.covariance, rtol=1e-12, atol=1e-12 * np.abs(kf.covariance).max())
    np.testing.assert_allclose(fde.x, kf.x, rtol=1e-12, atol=1e-12 * np.abs(kf.x).max())


def test_fde_false_alarm_rate_matches_the_configured_probability():
    """On clean epochs of the exact model the chi-square test alarms at the configured rate: the count of
    alarms over 4000 epochs lies inside its two-sided 99.9% binomial interval."""
    rng = np.random.default_rng(5)
    B, C = 4000, 9
    H = gnss_rows(rng, B, C, rates=True)
    m = H.shape[1]
    P = prior(rng, B)
    R = rng.uniform(1, 9, (B, m))
    dz = draw(rng, H, P, R)
    mask = np.ones((B, m), bool)
    for p_fa in (0.01, 0.05):
        _, _, alarm, _ = fde_screen(dz, H, P, R, mask, FdeConfig(p_fa=p_fa, p_gate=0.0))
        lo, hi = binom.ppf([0.0005, 0.9995], B, p_fa)
        assert lo <= alarm.sum() <= hi, (p_fa, alarm.sum(), lo, hi)
    # a test that ignored the degrees of freedom (threshold of 1 dof) would alarm on most epochs
    assert alarm.sum() < 0.2 * B


def test_fde_keeps_the_rows_the_unknowns_need():
    """Every row an outlier: the screen stops at min_rows rows per type (redundancy gone), never below."""
    rng = np.random.default_rng(6)
    B, C = 8, 7
    H = gnss_rows(rng, B, C, rates=True)
    P = prior(rng, B, scale=0.01)
    R = np.ones((B, 2 * C))
    dz = rng.uniform(200, 400, (B, 2 * C)) * rng.choice([-1, 1], (B, 2 * C))
    keep, n_excl, alarm, _ = fde_screen(dz, H, P, R, np.ones((B, 2 * C), bool), FdeConfig(min_rows=4))
    assert alarm.all()
    np.testing.assert_array_equal(keep[:, :C].sum(1), 4)
    np.testing.assert_array_equal(keep[:, C:].sum(1), 4)
    np.testing.assert_array_equal(n_excl, 2 * (C - 4))


@pytest.mark.parametrize("inner", [f for f in PLAIN_FORMS if f != "kf"])
def test_fde_composes_with_every_form(inner):
    """``<form>+fde`` equals ``kf+fde`` in float64 over 30 epochs with outliers: the screen only uses the form
    interface (the same rows excluded, covariance and state to 1e-8 relative)."""
    rng = np.random.default_rng(7)
    B, C = 3, 8
    P0 = prior(rng, B)
    a, b = make_form(f"{inner}+fde", P0), make_form("kf+fde", P0)
    assert type(a.inner) is FORMS[inner]
    for k in range(30):
        Phi = np.eye(N) + 0.02 * rng.normal(size=(B, N, N))
        Q = 0.05 * np.broadcast_to(np.eye(N), (B, N, N))
        a.predict(Phi, Q)
        b.predict(Phi, Q)
        H = gnss_rows(rng, B, C)
        R = rng.uniform(1, 4, (B, C))
        dz = draw(rng, H, b.covariance, R) + np.where(rng.random((B, C)) < 0.15, 60.0, 0.0)
        a.update(dz, H, R)
        b.update(dz, H, R)
        np.testing.assert_array_equal(a.excluded(), b.excluded())
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=0, atol=1e-8 * np.abs(b.covariance).max())
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-8 * np.abs(b.x).max() + 1e-12)


def test_fde_around_an_adaptive_law_forwards_its_parameters():
    P0 = prior(np.random.default_rng(8), 3)
    f = make_form("sage-husa+fde", P0)
    assert isinstance(f, FaultExclusion) and "b" in f.params()
    f.set_params(b=np.array([0.9, 0.95, 0.99]))
    np.testing.assert_array_equal(f.inner.params()["b"], [0.9, 0.95, 0.99])
    with pytest.raises(ValueError, match="b"):
        f.set_params(b=2.0)
    with pytest.raises(ValueError, match="unknown adaptive parameter"):
        make_form("kf-fde", P0).set_params(b=0.9)
    with pytest.raises(ValueError, match="unknown filter method"):
        make_form("nope+fde", P0)


def test_fde_config_errors_name_the_field():
    for kw, field in ((dict(p_fa=0.0), "p_fa"), (dict(p_gate=-1.0), "p_gate"), (dict(min_rows=0), "min_rows"),
                      (dict(p_fa=float("nan")), "p_fa")):
        with pytest.raises(ValueError, match=field):
            FdeConfig(**kw)
    for kw, field in ((dict(weight="tukey"), "weight"), (dict(k0=3.0, k1=2.0), "k1"), (dict(c=0.0), "c"),
                      (dict(max_iter=0), "max_iter")):
        with pytest.raises(ValueError, match=field):
            RobustConfig(**kw)
    for kw, field in ((dict(rho=0.0), "rho"), (dict(n_iter=0), "n_iter"), (dict(scale_min=2.0), "scale_min")):
        with pytest.raises(ValueError, match=field):
            VbConfig(**kw)


# ------------------------------------------------------------------------------------------ M-estimation
@pytest.mark.parametrize("method", ["kf-igg3", "kf-huber"])
def test_m_estimators_resist_an_outlier_that_drags_kf(method):
    """Static position, 8 satellites, one of them 50 m off at every epoch: kf is dragged by metres (~20 m in the
    other satellites' ranges), IGG-III rejects the satellite (weight 0) and stays within 1 m, Huber's bounded
    influence keeps the pull under a tenth of kf's."""
    rng = np.random.default_rng(9)
    B, C = 4, 8
    H = gnss_rows(rng, B, C)
    P0 = np.broadcast_to(np.eye(N) * 100.0, (B, N, N)).copy()
    forms = {m: make_form(m, P0) for m in ("kf", method)}
    x = rng.normal(size=(B, N))
    R = np.ones((B, C))
    for k in range(20):
        v = rng.normal(size=(B, C))
        v[:, 0] += 50.0
        for f in forms.values():
            f.predict(np.broadcast_to(np.eye(N), (B, N, N)), 1e-6 * np.broadcast_to(np.eye(N), (B, N, N)))
            f.update((H @ (x - f.x)[..., None])[..., 0] + (H @ f.x[..., None])[..., 0] + v, H, R)
    err = {m: np.abs((H @ (f.x - x)[..., None])[..., 0][:, 1:]).max() for m, f in forms.items()}
    assert err["kf"] > 10.0 and err[method] < (1.0 if method == "kf-igg3" else 0.1 * err["kf"]), err
    if method == "kf-igg3":
        np.testing.assert_array_equal(forms[method].excluded(), np.ones(B, int))


def test_m_estimators_keep_lock_when_every_row_looks_bad():
    """A state 500 m off with a tight P: IGG-III would give every row weight 0; the safeguard keeps min_rows rows
    so that the filter still updates."""
    rng = np.random.default_rng(10)
    B, C = 3, 8
    H = gnss_rows(rng, B, C)
    P = prior(rng, B, scale=1e-3)
    dz = (H @ np.full((B, N, 1), 500.0))[..., 0] + rng.normal(size=(B, C))
    gam, _, _ = robust_weights(dz, H, P, np.ones((B, C)), np.ones((B, C), bool), RobustConfig(min_rows=4))
    np.testing.assert_array_equal((gam > 0).sum(1), 4)
    gam, _, _ = robust_weights(dz, H, P, np.ones((B, C)), np.ones((B, C), bool), RobustConfig(min_rows=0))
    np.testing.assert_array_equal((gam > 0).sum(1), 0)


# ------------------------------------------------------------------------------------------ VB-AKF
def test_vb_akf_converges_to_a_known_variance_in_a_static_case():
    """Static state, satellites whose true variance is 9x (and 0.25x with no floor) the reported one: the
    scales beta / alpha settle within 20% of the truth (rho = 0.99: a memory of ~100 epochs)."""
    rng = np.random.default_rng(11)
    B, C = 4, 10
    H = gnss_rows(rng, B, C)
    keys = np.broadcast_to(np.arange(C), (B, C)).copy()
    true = np.where(np.arange(C) < 3, 9.0, np.where(np.arange(C) < 6, 0.25, 1.0))
    law = VariationalR(np.broadcast_to(np.eye(N) * 100.0, (B, N, N)).copy(),
                       config=VbConfig(rho=0.99, scale_min=0.01))
    x = rng.normal(size=(B, N))
    scales = []
    for k in range(1500):
        law.predict(np.broadcast_to(np.eye(N), (B, N, N)), 1e-8 * np.broadcast_to(np.eye(N), (B, N, N)))
        z = (H @ (x - law.x)[..., None])[..., 0] + rng.normal(size=(B, C)) * np.sqrt(true)
        law.update(z, H, np.ones((B, C)), keys=keys)
        if k >= 1000:
            scales.append(law.satellite_scales(keys))
    est = np.mean(scales, axis=(0, 1))
    np.testing.assert_allclose(est, true, rtol=0.2)


def test_vb_akf_per_row_rho_and_satellites_follow_their_keys():
    P0 = np.broadcast_to(np.eye(N), (2, N, N)).copy()
    law = make_form("vb-akf", P0)
    law.set_params(rho=np.array([0.5, 0.99]))
    np.testing.assert_array_equal(law.params()["rho"], [0.5, 0.99])
    with pytest.raises(ValueError, match="rho"):
        law.set_params(rho=1.5)


# ------------------------------------------------------------------------------------------ dtypes, registry
@pytest.mark.parametrize("method", ["kf-fde", "kf-igg3", "kf-huber", "vb-akf", "sage-husa+fde"])
def test_float32_agrees_with_float64(method):
    rng = np.random.default_rng(12)
    B, C = 3, 9
    P0 = prior(rng, B, scale=25.0)
    f64, f32 = make_form(method, P0, dtype=np.float64), make_form(method, P0, dtype=np.float32)
    keys = measurement_keys(np.broadcast_to(np.arange(C), (B, C)), with_rate=False)
    for k in range(25):
        Phi = np.eye(N) + 0.01 * rng.normal(size=(B, N, N))
        Q = 0.01 * np.broadcast_to(np.eye(N), (B, N, N))
        f64.predict(Phi, Q)
        f32.predict(Phi.astype(np.float32), Q.astype(np.float32))
        H = gnss_rows(rng, B, C)
        R = rng.uniform(4, 9, (B, C))
        dz = draw(rng, H, f64.covariance, R) + np.where(rng.random((B, C)) < 0.1, 80.0, 0.0)
        f64.update(dz, H, R, keys=keys)
        f32.update(dz.astype(np.float32), H.astype(np.float32), R.astype(np.float32), keys=keys)
    assert f32.covariance.dtype == np.float32
    np.testing.assert_allclose(f32.covariance, f64.covariance, rtol=0, atol=2e-3 * np.abs(f64.covariance).max())
    np.testing.assert_allclose(f32.x, f64.x, rtol=0, atol=2e-3 * np.abs(f64.x).max() + 1e-6)


def test_the_laws_take_factories_not_names():
    """One-way registry: a law is handed its inner form's factory; a method name is the registry's business."""
    P0 = np.broadcast_to(np.eye(4), (2, 4, 4)).copy()
    with pytest.raises(ValueError, match="inner"):
        RobustUpdate(P0, inner="kf")
    f = law_factory(RobustUpdate, FORMS["svd-kf"], weight="huber")
    assert f(P0).config.weight == "huber" and type(f(P0).inner) is FORMS["svd-kf"]


def test_forms_and_laws_do_not_import_the_registry():
    """The import direction is one way: nothing under nav_filters/forms or nav_filters/adaptive names the
    registry (checked on the source, imports inside functions included)."""
    import ast
    from pathlib import Path

    import nav_filters
    root = Path(nav_filters.__file__).parent
    for sub in ("forms", "adaptive"):
        for path in (root / sub).glob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom):
                    assert "registry" not in (node.module or "") and all(a.name != "registry" for a in node.names), \
                        f"{path.name} imports the registry"
                if isinstance(node, ast.Import):
                    assert all("registry" not in a.name for a in node.names), f"{path.name} imports the registry"
