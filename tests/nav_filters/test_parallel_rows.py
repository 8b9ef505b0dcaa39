"""The row kernels that run parallel over rows from 64 rows on (``kernels.row_kernel``) give every row the same
bits as the serial variant on a smaller batch: the rows are independent and each row's arithmetic does not
depend on the chunking. Each check runs a 70-row batch (parallel, chunked) against its two halves of 35 rows
(serial, one chunk), for float64 and float32."""
import copy

import numpy as np
import pytest

import nav_filters.forms  # noqa: F401  (registers the adaptive laws before they are imported below)
from nav_filters.adaptive.innovation import fit_split, innovation_traces
from nav_filters.forms.base import prepare_measurement, prepare_measurement_reference
from nav_filters.kernels import PARALLEL_MIN_BATCH, row_kernel
from nav_filters.measurements import gnss_innovations

from test_compiled_update import _geometry, _gnss_H, spd  # noqa: E402

N = 17
B = 70
HALVES = (slice(0, 35), slice(35, 70))


def test_the_split_is_serial_and_parallel():
    assert row_kernel("s", "p", B) == ("p", min(B, 4 * __import__("numba").get_num_threads()))
    assert row_kernel("s", "p", 35) == ("s", 1) and 35 < PARALLEL_MIN_BATCH <= B


def _same(full, parts, name=""):
    for a, pa in zip(full, zip(*parts)):
        if a is None:
            continue
        b = np.concatenate(pa)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_gnss_innovations_rows(dtype):
    rng = np.random.default_rng(1)
    C = 9
    r, v, sat, sv = _geometry(rng, B, C)
    mask = rng.random((B, C)) > 0.3
    clk, drift = rng.normal(0, 100, B), rng.normal(0, 1, B)
    pr = np.linalg.norm(sat - r[:, None], axis=-1) + rng.normal(0, 5, (B, C))
    prr = rng.normal(0, 100, (B, C))
    pv, prv = rng.uniform(1, 10, (B, C)), rng.uniform(0.01, 0.1, (B, C))
    args = (r, v, clk, drift, sat, sv, pr, prr, pv, prv, mask)
    full = gnss_innovations(*args, dtype=dtype)
    _same(full, [gnss_innovations(*(a[h] for a in args), dtype=dtype) for h in HALVES])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("full_r", [False, True])
def test_prepare_measurement_rows_and_errors(dtype, full_r):
    rng = np.random.default_rng(3)
    m = 12
    dz, H = rng.normal(size=(B, m)), rng.normal(size=(B, m, N))
    R = spd(rng, B, m) if full_r else rng.uniform(0.5, 2.0, (B, m))
    mask = rng.random((B, m)) < 0.7
    dz[~mask], H[~mask] = np.nan, np.inf
    full = prepare_measurement(dz, H, R, mask, dtype)
    _same(full, [prepare_measurement(dz[h], H[h], R[h], mask[h], dtype) for h in HALVES])
    _same(full, [prepare_measurement_reference(dz, H, R, mask, dtype)])
    i = np.argwhere(mask[B - 1])[0, 0]
    dz[B - 1, i] = np.nan  # a bad value on a valid row of the last chunk: the reference's error
    msgs = []
    for f in (prepare_measurement, prepare_measurement_reference):
        with pytest.raises(ValueError) as e:
            f(dz, H, R, mask, dtype)
        msgs.append(str(e.value))
    assert msgs[0] == msgs[1] and f"batch row {B - 1}" in msgs[0]


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_traces_and_fit_split_rows(dtype):
    rng = np.random.default_rng(7)
    m = 14
    H = _gnss_H(rng, B, m // 2).astype(dtype)
    mask = rng.random((B, m)) < 0.85
    H[~mask] = 0
    dz = np.where(mask, rng.normal(size=(B, m)) * 3, 0).astype(dtype)
    P, Q, R = (spd(rng, B, k).astype(dtype) for k in (N, N, m))
    for q in (Q, None):
        t = innovation_traces(dz, H, P, q, R, mask)
        parts = [innovation_traces(dz[h], H[h], P[h], None if q is None else q[h], R[h], mask[h]) for h in HALVES]
        keys = ("energy", "tr_m", "tr_q", "tr_r", "n_used")
        _same([getattr(t, k) for k in keys], [[getattr(p, k) for k in keys] for p in parts], "traces")
        f = fit_split(dz, H, R, mask, P, q, fast=True)
        parts = [fit_split(dz[h], H[h], R[h], mask[h], P[h], None if q is None else q[h], fast=True) for h in HALVES]
        keys = ("e_fit", "e_res", "dof", "p", "tr_m", "tr_q", "n", "n_other")
        _same([getattr(f, k) for k in keys], [[getattr(p, k) for k in keys] for p in parts], "fit_split")
        assert (f.dof > 0).any()


def test_feedback_rows():
    from envs.episodes import navigator_for
    from envs.sim.world import generate_world
    rng = np.random.default_rng(6)
    dx = rng.normal(size=(B, N)) * np.r_[[1e-3, 1e-5, 1e-6], [0.1] * 3, [1.0] * 3, [1e-6] * 6, 10.0, 1.0]
    dx[1, :3] = [0.3, -0.2, 0.1]  # large angle: Rodrigues, not the series
    dx[66, 5] = np.nan  # becomes non-finite in the last chunk: flagged and parked
    frozen = np.arange(B) == 2  # a diverged row: unchanged
    nav = navigator_for(generate_world("open-sky", list(range(B))), "sage-husa")
    nav.diverged[:] = frozen
    nav._feedback(dx.copy())  # 70 rows: the parallel variant
    assert nav.diverged[66] and nav.diverged[2] and nav.diverged.sum() == 2
    for h in HALVES:  # the same rows, 35 at a time: the serial variant
        sub = navigator_for(generate_world("open-sky", list(range(B))[h]), "sage-husa")
        sub.diverged[:] = frozen[h]
        sub._feedback(dx[h].copy())
        for k in ("r", "v", "C", "bg", "ba", "clk", "drift", "diverged"):
            np.testing.assert_array_equal(getattr(nav, k)[h], getattr(sub, k), err_msg=k)
