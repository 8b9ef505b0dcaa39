"""The compiled epochs of the adaptive laws (``sage_husa_rows.satellite_epoch``, ``strong_tracking_rows.st_epoch``
and ``ma_epoch``) are the Python sequence of ``AdaptiveLaw._update`` (plan, fused update, commit) bit for bit,
and commit nothing when an innovation covariance is not positive definite."""
import copy
import types

import numpy as np
import pytest

import nav_filters.adaptive.sage_husa as sage_husa
import nav_filters.adaptive.strong_tracking as strong_tracking
from nav_filters.adaptive.base import AdaptiveLaw
from nav_filters.measurements import N_SAT_KEYS
from nav_filters.registry import make_form

N = 17


def _spd(rng, B, scale):
    A = rng.normal(size=(B, N, N))
    return scale * (A @ A.mT / N + np.eye(N))


def _epoch(rng, B, C, dtype):
    """One epoch's transition, process noise and GNSS measurement (C channels: pseudoranges then rates, the
    navigator's H layout: position 6:9 and clock 15, velocity 3:6 and drift 16) with satellite keys."""
    Phi = (np.eye(N) + 0.01 * rng.normal(size=(B, N, N))).astype(dtype)
    Q = _spd(rng, B, 1e-3).astype(dtype)
    H = np.zeros((B, 2 * C, N))
    los = rng.normal(size=(B, C, 3))
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    H[:, :C, 6:9], H[:, :C, 15] = los, 1.0
    H[:, C:, 3:6], H[:, C:, 16] = los, 1.0
    sat = np.stack([rng.choice(40, C, replace=False) for _ in range(B)])  # satellites come and go
    keys = np.concatenate([sat, N_SAT_KEYS + sat], 1)
    mask = np.repeat(rng.random((B, C)) < 0.85, 2, axis=1)
    keys[~mask] = -1
    R = np.concatenate([np.full((B, C), 9.0), np.full((B, C), 0.01)], 1) * rng.uniform(0.5, 2.0, (B, 2 * C))
    dz = rng.normal(size=(B, 2 * C)) * np.sqrt(R) * rng.choice([1.0, 1.0, 1.0, 8.0], (B, 2 * C))  # outliers
    return Phi, Q, dz.astype(dtype), H.astype(dtype), R.astype(dtype), mask, keys


def _state(law):
    """Every array of the law and its inner form (the compiled epoch's scratch aside)."""
    out = {}
    for owner, obj in (("law", law), ("inner", law.inner)):
        for k, v in vars(obj).items():
            if isinstance(v, np.ndarray):
                out[f"{owner}.{k}"] = v
            elif isinstance(v, dict):
                out.update({f"{owner}.{k}[{j}]": a for j, a in v.items() if isinstance(a, np.ndarray)})
    return out


def _python_path(law):
    """``law`` running the Python sequence of ``AdaptiveLaw._update`` instead of the compiled epoch."""
    law._has_compiled_epoch = types.MethodType(AdaptiveLaw._has_compiled_epoch, law)
    return law


PARAMS = {"sage-husa": {"b": (0.9, 0.999)}, "sage-husa-r": {"b": (0.9, 0.999)},
          "stkf": {"rho": (0.5, 0.99), "softening": (0.5, 2.0)},
          "ma-stkf": {"b": (0.9, 0.99), "softening": (0.5, 2.0), "fading_scale": (0.5, 2.0),
                      "fault_threshold": (3.0, 20.0)}}
EPOCHS = {"sage-husa": (sage_husa, "satellite_epoch"), "sage-husa-r": (sage_husa, "satellite_epoch"),
          "stkf": (strong_tracking, "st_epoch"), "ma-stkf": (strong_tracking, "ma_epoch")}


@pytest.mark.parametrize("method", list(EPOCHS))
@pytest.mark.parametrize("dtype,B", [(np.float64, 5), (np.float32, 5), (np.float64, 70)])  # 70: parallel
def test_compiled_epoch_is_the_python_sequence_bit_for_bit(monkeypatch, method, dtype, B):
    rng = np.random.default_rng(3)
    law = make_form(method, _spd(rng, B, 10.0), dtype=dtype)
    assert law.set_fused(True)
    law.set_params(**{k: rng.uniform(lo, hi, B) for k, (lo, hi) in PARAMS[method].items()})  # per row
    ref = _python_path(copy.deepcopy(law))
    calls = []
    module, name = EPOCHS[method]
    monkeypatch.setattr(module, name, lambda *a, f=getattr(module, name): calls.append(1) or f(*a))
    faded = rejected = False
    for it in range(14):  # past the warm-up (10 epochs): the Q law and the satellite tables at work
        Phi, Q, dz, H, R, mask, keys = _epoch(rng, B, 8, dtype)
        if it == 5:
            mask[0] = False  # a row without measurements
        if it >= 11:  # no outliers, and a state error the filter has not predicted: strong tracking fades
            dz = (rng.normal(size=dz.shape) * np.sqrt(R) + (H @ (30.0 * rng.normal(size=(B, N, 1))))[..., 0])
            dz = dz.astype(dtype)
        results = []
        for f in (law, ref):
            f.predict(Phi, Q)
            results.append(f.update(dz, H, R, mask, keys=keys))
        for name in ("nis", "n_used", "innovation", "innovation_var", "applied"):
            a, b = getattr(results[0], name), getattr(results[1], name)
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), (it, name)
        faded = faded or bool((getattr(law, "_lambda", np.ones(1)) > 1).any())
        rejected = rejected or bool(getattr(law, "_rejected", np.zeros(1, bool)).any())
        got, want = _state(law), _state(ref)
        assert got.keys() == want.keys()
        for k in want:
            assert got[k].dtype == want[k].dtype and got[k].tobytes() == want[k].tobytes(), (it, k)
    assert len(calls) == 14
    if method.startswith("sage-husa"):  # the Q law and the satellite tables were at work
        assert law._q_init.all() == (method == "sage-husa") and (law._sat_count > 0).any()
    elif method == "stkf":  # the fading factor was at work
        assert faded
    else:  # the fault test and the measurement factors were at work
        assert rejected and (law._alpha > 2).all()


@pytest.mark.parametrize("method", ["sage-husa", "stkf", "ma-stkf"])
def test_compiled_epoch_commits_nothing_when_S_is_not_positive_definite(method):
    rng = np.random.default_rng(8)
    B = 4
    law = make_form(method, _spd(rng, B, 10.0))
    law.set_fused(True)
    for _ in range(3):
        Phi, Q, dz, H, R, mask, keys = _epoch(rng, B, 6, np.float64)
        law.predict(Phi, Q)
        law.update(dz, H, R, mask, keys=keys)
    law.inner.P[2] = -law.inner.P[2]  # row 2: S = H P- H^T + R not positive definite
    Phi, Q, dz, H, R, mask, keys = _epoch(rng, B, 6, np.float64)
    law.predict(Phi, Q)
    before = {k: v.copy() for k, v in _state(law).items()}
    ref = _python_path(copy.deepcopy(law))
    for f in (law, ref):
        with pytest.raises(np.linalg.LinAlgError):
            f.update(dz, H, R, mask, keys=keys)
    after = _state(law)
    assert set(before) - set(after) == {"law._Phi_acc", "law._Q_acc"}  # taken into the epoch's context
    for k in after:
        assert after[k].tobytes() == before[k].tobytes(), k
    for f in (law, ref):  # the epoch is kept for a retry, as on the Python path
        assert f._ctx.pending and not f._ctx.applied and f._ctx.Phi.tobytes() == before["law._Phi_acc"].tobytes()
