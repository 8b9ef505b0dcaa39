"""Variance models of the reported pseudorange sigma (``sigma_model``, envs.sim.sigma_models): the formulas
against hand-computed values, the model's validation, and the simulated receiver that applies it."""
import dataclasses
import math

import numpy as np
import pytest

from envs.sim.gnss import ReceiverConfig
from envs.sim.scenarios import get_scenario
from envs.sim.sigma_models import (MIN_ELEVATION_RAD, SIGMA_EPSILON_CODE_M2HZ, SigmaModel, elevation_cn0_variance,
                                   elevation_variance, model_pr_sigma, sigma_epsilon_variance)
from envs.sim.world import generate_world

D30, D90 = math.radians(30.0), math.radians(90.0)


# ------------------------------------------------------------------------------------------- the formulas
def test_elevation_model_by_hand():
    # sin 30 deg = 1/2: 0.3^2 + 0.3^2 * 4 = 0.45; zenith: 0.09 + 0.09 = 0.18
    np.testing.assert_allclose(elevation_variance([D30, D90], 0.3, 0.3), [0.45, 0.18], rtol=1e-14)
    np.testing.assert_allclose(elevation_variance(D30, 1.0, 2.0), 1.0 + 4.0 * 4.0, rtol=1e-14)
    # below the 1-deg floor (and negative elevations) the floor's value: 1 / sin^2(1 deg) = 3283.0
    floor = 0.09 + 0.09 / math.sin(math.radians(1.0)) ** 2
    np.testing.assert_allclose(elevation_variance([0.0, -0.1, MIN_ELEVATION_RAD], 0.3, 0.3), [floor] * 3,
                               rtol=1e-14)
    assert 295.0 < floor < 296.0


def test_sigma_epsilon_by_hand():
    # C 10^(-C/N0 / 10): 1.1e4 * 1e-4 = 1.1 m^2 at 40 dB-Hz, ten times less per 10 dB
    np.testing.assert_allclose(sigma_epsilon_variance([40.0, 50.0, 30.0], 1.1e4), [1.1, 0.11, 11.0], rtol=1e-14)
    assert SIGMA_EPSILON_CODE_M2HZ == 1.1e4
    # 0.59 m at 45 dB-Hz (the documented figure)
    assert abs(math.sqrt(sigma_epsilon_variance(45.0, SIGMA_EPSILON_CODE_M2HZ)) - 0.59) < 0.005


def test_elevation_cn0_by_hand():
    # Groves eq. 9.168 at 30 deg, 40 dB-Hz (c/n0 = 1e4 Hz): (0.3^2 + 1.1e4 / 1e4) * 4 = 4.76
    np.testing.assert_allclose(elevation_cn0_variance(D30, 40.0, 0.3, math.sqrt(1.1e4)), 4.76, rtol=1e-13)
    # the range-acceleration term: + (0.1 s^2 * 2 m/s^2)^2 inside the bracket -> + 0.04 * 4
    np.testing.assert_allclose(elevation_cn0_variance(D30, 40.0, 0.3, math.sqrt(1.1e4), 0.1, 2.0), 4.92,
                               rtol=1e-13)
    # at zenith it is the zenith term plus the SIGMA-epsilon variance with C = sigma_c^2
    np.testing.assert_allclose(elevation_cn0_variance(D90, 37.0, 0.5, 20.0),
                               0.25 + sigma_epsilon_variance(37.0, 400.0), rtol=1e-14)


def test_models_broadcast_over_leading_axes():
    rng = np.random.default_rng(3)
    el = rng.uniform(0.0, math.pi / 2, (2, 3, 4))
    cn0 = rng.uniform(20.0, 50.0, (2, 3, 4))
    for name in ("elevation", "sigma-epsilon", "elevation-cn0"):
        m = SigmaModel(name)
        v = m.variance(el, cn0)
        assert v.shape == (2, 3, 4) and np.all(v > 0)
        np.testing.assert_array_equal(v[1, 2], m.variance(el[1, 2], cn0[1, 2]))     # row by row the same
    np.testing.assert_allclose(SigmaModel("elevation", a_m=0.5, b_m=0.2).variance(el, None),
                               0.25 + 0.04 / np.sin(np.maximum(el, MIN_ELEVATION_RAD)) ** 2, rtol=1e-14)


def test_model_pr_sigma_masks_and_names_a_missing_cn0():
    reported = np.array([[5.0, 8.0, 0.0]])
    mask = np.array([[True, True, False]])
    el = np.array([[D30, D90, 0.0]])
    cn0 = np.array([[40.0, 50.0, 0.0]])
    assert model_pr_sigma(SigmaModel(), reported, mask, el, cn0) is reported          # 'receiver': as is
    np.testing.assert_allclose(model_pr_sigma(SigmaModel("sigma-epsilon"), reported, mask, el, cn0),
                               [[math.sqrt(1.1), math.sqrt(0.11), 0.0]], rtol=1e-14)
    np.testing.assert_allclose(model_pr_sigma(SigmaModel("elevation"), reported, mask, el, None),
                               [[math.sqrt(0.45), math.sqrt(0.18), 0.0]], rtol=1e-14)   # no C/N0 needed
    with pytest.raises(ValueError, match=r"^obs\.23O: sigma_model 'elevation-cn0' needs the C/N0 .* 1 of 2 "):
        model_pr_sigma(SigmaModel("elevation-cn0"), reported, mask, el, np.array([[40.0, 0.0, 0.0]]), "obs.23O")
    with pytest.raises(ValueError, match="this source has none"):
        model_pr_sigma(SigmaModel("sigma-epsilon"), reported, mask, el, None, "x")


@pytest.mark.parametrize("kw, words", [
    (dict(name="snr"), "SigmaModel.name 'snr' is unknown"),
    (dict(name="elevation", a_m=-0.1), r"SigmaModel.a_m must be >= 0, got -0.1"),
    (dict(name="sigma-epsilon", c_m2hz=float("nan")), "SigmaModel.c_m2hz must be a finite number"),
    (dict(name="elevation-cn0", zenith_m=True), "SigmaModel.zenith_m must be a finite number"),
    (dict(name="elevation", a_m=0.0, b_m=0.0), "SigmaModel.a_m: the 'elevation' model needs a parameter > 0"),
    (dict(name="sigma-epsilon", c_m2hz=0.0), "SigmaModel.c_m2hz: the 'sigma-epsilon' model needs"),
])
def test_bad_sigma_model_is_one_clear_error(kw, words):
    with pytest.raises(ValueError, match=words):
        SigmaModel(**kw)
    with pytest.raises(ValueError, match="ReceiverConfig.sigma_model must be a SigmaModel"):
        ReceiverConfig(sigma_model="elevation")
    assert SigmaModel("elevation", c_m2hz=0.0).name == "elevation"       # other models' parameters: ignored


# ------------------------------------------------------------------------------------ the simulated receiver
def test_simulated_receiver_reports_the_models_sigma_and_keeps_the_errors():
    base = get_scenario("urban", duration_s=20.0)
    default = generate_world(base, [0, 1])
    for name in ("elevation", "sigma-epsilon", "elevation-cn0"):
        model = SigmaModel(name)
        w = generate_world(base.replace(receiver=ReceiverConfig(elevation_mask_deg=15.0, sigma_model=model)),
                           [0, 1])
        g, d = w.gnss, default.gnss
        for f in ("pr", "pr_error_m", "pr_var_true", "prr_sigma", "cn0_dbhz", "elevation", "mask"):
            np.testing.assert_array_equal(getattr(g, f), getattr(d, f), err_msg=f)      # the truth is untouched
        m = g.mask
        want = np.sqrt(model.variance(g.elevation, g.cn0_dbhz))
        np.testing.assert_allclose(g.pr_sigma[m], want[m], rtol=1e-12)
        assert np.all(g.pr_sigma[~m] == 0.0) and not np.allclose(g.pr_sigma[m], d.pr_sigma[m])


def test_simulated_sigma_model_keeps_the_mismatch_factor():
    """A SigmaMismatch still multiplies the reported sigma: the factor (mismatched / honest) is the same with
    the default model and with a variance model."""
    mis = get_scenario("noise-mismatch", duration_s=60.0)
    honest = mis.replace(events=dataclasses.replace(mis.events, mismatch=None))
    elev = ReceiverConfig.dual_frequency(sigma_model=SigmaModel("elevation"))
    ratios = []
    for scen in (mis, mis.replace(receiver=elev)):
        a, b = generate_world(scen, [3]).gnss, generate_world(
            honest.replace(receiver=scen.receiver), [3]).gnss
        ratios.append(a.pr_sigma[a.mask] / b.pr_sigma[b.mask])
    np.testing.assert_allclose(ratios[0], ratios[1], rtol=1e-12)
    assert np.ptp(ratios[0]) > 0.5                                                  # factors do vary
