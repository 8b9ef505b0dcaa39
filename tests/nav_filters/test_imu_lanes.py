"""The averaged-mode propagation with rows in SIMD lanes (nav_filters.imu_lanes) is the row kernel's arithmetic.

Its mechanization must give the bits of the row kernel's (the composing modes run the same helper, row by
row), whatever the block a row falls in, for rows turning slowly (the series coefficients) and fast (the
scalar pass with sin and cos); its sums the numpy integrals (``test_kernels.py``) and the same accumulators
when an epoch arrives in pieces.
"""
import numpy as np
import pytest

from nav_filters import imu_lanes as IL
from nav_filters import kernels as K
from nav_filters.propagation import propagate_epoch
from nav_filters.ins import _earth_rate_matrices_np


def _inputs(B, n, seed=0, fast_every=0):
    from envs.sim.world import generate_world
    w = generate_world("urban", list(range(seed, seed + B)))
    rng = np.random.default_rng(seed)
    f = np.ascontiguousarray(w.imu.f_b[:, 1:n + 1])
    ww = np.ascontiguousarray(w.imu.w_b[:, 1:n + 1])
    if fast_every:  # every fast_every-th row turns at a few rad/s: |w h|^2 >= 1e-4 at h = 0.01 s
        ww[::fast_every] += rng.normal(0.0, 3.0, (ww[::fast_every].shape[0], 1, 3))
    return dict(r=w.init.r_e.copy(), v=w.init.v_e.copy(), C=w.init.C_eb.copy(),
                bg=rng.normal(0, 1e-5, (B, 3)), ba=rng.normal(0, 1e-2, (B, 3)), clk=rng.normal(0, 10.0, B),
                drift=rng.normal(0, 1.0, B), f=f, w=ww)


def _run(inp, h, integrate, orthonormalize=False, start=True, acc=None):
    B = inp["f"].shape[0]
    r, v, C, clk = inp["r"].copy(), inp["v"].copy(), inp["C"].copy(), inp["clk"].copy()
    Cz, P, QH, Qh = _earth_rate_matrices_np(h)
    qg, qa = np.array([1e-8, 2e-8, 3e-8]), np.array([1e-4, 1e-4, 2e-4])
    qd = np.r_[qg, qa, np.zeros(3), np.full(6, 1e-12), 0.01, 0.04]
    A, S = (np.full((B, 17, 17), np.nan), np.full((B, 17, 17), np.nan)) if acc is None else acc
    propagate_epoch(r, v, C, inp["bg"], inp["ba"], clk, inp["drift"], inp["f"], inp["w"], h, P, QH, Qh, Cz,
                    qg, qa, qd, -1 / 300, -1 / 600, A, S, False, orthonormalize, K.F_NONZERO, integrate, start)
    return r, v, C, clk, A, S


@pytest.mark.parametrize("B", [1, IL.LANES + 1, 70])   # one lane; a full block and a partial one; parallel
@pytest.mark.parametrize("orthonormalize", [False, True])
def test_lanes_mechanize_the_row_kernels_bits(B, orthonormalize):
    inp = _inputs(B, 30, fast_every=3)
    th2 = ((inp["w"] - inp["bg"][:, None]) * 0.01) ** 2
    assert (th2.sum(-1) >= 1e-4).any() and (B == 1 or (th2.sum(-1) < 1e-4).any())   # both coefficient branches
    lanes = _run(inp, 0.01, True, orthonormalize)
    rows = _run(inp, 0.01, False, orthonormalize)
    for a, b in zip(lanes[:4], rows[:4]):
        np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(lanes[4])) and np.all(np.isfinite(lanes[5]))   # start: every entry written


def test_a_row_does_not_depend_on_its_block():
    inp = _inputs(IL.LANES + 7, 20, seed=4, fast_every=5)
    full = _run(inp, 0.01, True)
    for i in (0, 5, IL.LANES, IL.LANES + 6):
        one = _run({k: v[i:i + 1] for k, v in inp.items()}, 0.01, True)
        for a, b in zip(one, full):
            np.testing.assert_array_equal(a[0], b[i])


def test_an_epoch_in_pieces_accumulates_the_same_integrals():
    inp = _inputs(40, 24, seed=2)
    r, v, C, clk, A, S = _run(inp, 0.01, True)
    first = {k: (x[:, :10] if k in ("f", "w") else x) for k, x in inp.items()}
    r1, v1, C1, clk1, A1, S1 = _run(first, 0.01, True)
    rest = dict(inp, r=r1, v=v1, C=C1, clk=clk1, f=inp["f"][:, 10:], w=inp["w"][:, 10:])  # (strided views)
    r2, v2, C2, clk2, A2, S2 = _run(rest, 0.01, True, start=False, acc=(A1, S1))
    for a, b in ((r2, r), (v2, v), (C2, C), (clk2, clk)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(A2, A, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(S2, S, rtol=1e-12, atol=1e-30)
