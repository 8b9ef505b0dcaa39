"""The tightly coupled measurement model: H against finite differences, masking, DOP."""
import numpy as np

from earth import geodetic_to_ecef
from nav_filters.error_model import CLK, DRIFT, POS, VEL
from nav_filters.measurements import dop, gnss_innovations


def _geometry(B=2, C=6, seed=0):
    rng = np.random.default_rng(seed)
    r = geodetic_to_ecef(rng.uniform(0.2, 1.0, B), rng.uniform(-1, 1, B), rng.uniform(0, 500, B))
    v = rng.normal(0, 10, (B, 3))
    up = r / np.linalg.norm(r, axis=1, keepdims=True)
    d = rng.normal(size=(B, C, 3)) + 2.0 * up[:, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    sat = r[:, None, :] + 2.2e7 * d
    sv = rng.normal(0, 2500, (B, C, 3))
    return r, v, sat, sv


def test_H_matches_finite_differences_of_the_prediction():
    """z - h(x_nominal) changes by H dx when the *true* state moves by dx (x = correction convention)."""
    r, v, sat, sv = _geometry()
    B, C = sat.shape[:2]
    clk, drift = np.array([100.0, -50.0]), np.array([3.0, 0.2])
    mask = np.ones((B, C), bool)
    # measurements made by a 'true' receiver state = nominal + dx
    dx_pos, dx_vel, dx_clk, dx_drift = np.array([0.7, -0.4, 0.3]), np.array([0.05, 0.02, -0.03]), 1.5, 0.04
    _, H, _, _, _ = gnss_innovations(r, v, clk, drift, sat, sv, np.zeros((B, C)), np.zeros((B, C)),
                                     np.ones((B, C)), np.ones((B, C)), mask)
    z0 = gnss_innovations(r + dx_pos, v + dx_vel, clk + dx_clk, drift + dx_drift, sat, sv, np.zeros((B, C)),
                          np.zeros((B, C)), np.ones((B, C)), np.ones((B, C)), mask)[0]
    zn = gnss_innovations(r, v, clk, drift, sat, sv, np.zeros((B, C)), np.zeros((B, C)),
                          np.ones((B, C)), np.ones((B, C)), mask)[0]
    # innovation of the true measurement (= -z0 prediction part) against the nominal
    dz = -z0 - (-zn)
    x = np.zeros((B, 17))
    x[:, POS], x[:, VEL], x[:, CLK], x[:, DRIFT] = dx_pos, dx_vel, dx_clk, dx_drift
    pred = (H @ x[..., None])[..., 0]
    np.testing.assert_allclose(pred[:, :C], dz[:, :C], atol=2e-6)  # pseudorange rows: exact to 2nd order
    # rate rows: H neglects d(rho_dot)/dr ~ |v_rel|/rho ~ 3e-4 /s (times |dr| < 1 m): the standard model
    bound = 2 * np.linalg.norm(sv, axis=-1).max() / 2.0e7 * np.linalg.norm(dx_pos)
    assert np.max(np.abs(pred[:, C:] - dz[:, C:])) < bound
    assert np.max(np.abs(pred[:, C:] - dz[:, C:])) > 1e-7  # and it is really neglected (the check can fail)


def test_masked_channels_are_neutral_and_dop():
    r, v, sat, sv = _geometry(C=8)
    B, C = sat.shape[:2]
    mask = np.ones((B, C), bool)
    mask[0, 5:] = False
    dz, H, R, rm, u = gnss_innovations(r, v, np.zeros(B), np.zeros(B), sat, sv, np.full((B, C), 2.2e7),
                                       np.zeros((B, C)), np.ones((B, C)), np.ones((B, C)), mask)
    assert dz.shape == (B, 2 * C) and H.shape == (B, 2 * C, 17)
    assert np.all(dz[~rm] == 0) and np.all(R[~rm] == 1) and rm.sum() == 2 * mask.sum()
    g = dop(u, mask)
    assert np.all(g > 1) and np.all(np.isfinite(g))
    mask[1, 3:] = False
    assert np.isinf(dop(u, mask)[1])
    # pseudorange-only epochs (no Doppler) give m = C
    dz2, H2, *_ = gnss_innovations(r, v, np.zeros(B), np.zeros(B), sat, sv, np.zeros((B, C)), None,
                                   np.ones((B, C)), None, mask)
    assert dz2.shape == (B, C) and H2.shape == (B, C, 17)
