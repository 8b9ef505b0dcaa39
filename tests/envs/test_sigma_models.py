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


# ------------------------------------------------------------------------------------------ dataset specs
from envs.datasets.errors import shared_data_dir  # noqa: E402
from envs.datasets.spec import SHIPPED_SPECS, SPEC_DIR, DatasetSpecError, load_dataset_spec  # noqa: E402

DATA = shared_data_dir()
SMARTLOC_SPEC = SPEC_DIR / SHIPPED_SPECS["smartloc-potsdamer-platz"]
REACH_SPEC = SPEC_DIR / SHIPPED_SPECS["instinct-reach-static"]
needs_smartloc = pytest.mark.skipif(not (DATA / "smartloc" / "Berlin_Potsdamer_Platz_Input.txt").is_file(),
                                    reason=f"smartLoc data not found in {DATA / 'smartloc'} (../shared/data is "
                                           f"absent in a fresh clone; CI has it)")
needs_reach = pytest.mark.skipif(not (DATA / "instinct_tckf_static").is_dir(),
                                 reason=f"Reach M2 RINEX files not found in {DATA / 'instinct_tckf_static'}")


def _with_gnss_line(tmp_path, shipped, line: str, name="sigma-test"):
    """A copy of a shipped spec (its ${NAVGYM_DATA_DIR} paths still expand) with ``line`` added to [gnss]."""
    text = shipped.read_text().replace("[gnss]\n", f"[gnss]\n{line}\n", 1)
    text = "\n".join(f'name = "{name}"' if ln.startswith("name = ") else ln for ln in text.splitlines()) + "\n"
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return p


def test_spec_sigma_model_parsed_by_name_and_table(tmp_path):
    assert load_dataset_spec(SMARTLOC_SPEC).gnss.sigma_model == SigmaModel()           # default: receiver
    s = load_dataset_spec(_with_gnss_line(tmp_path, SMARTLOC_SPEC, 'sigma_model = "sigma-epsilon"'))
    assert s.gnss.sigma_model == SigmaModel("sigma-epsilon")
    assert s.scenario().receiver.sigma_model == SigmaModel("sigma-epsilon")            # the replay descriptor
    text = REACH_SPEC.read_text().replace("sigma0_m = 1.5\n", "")
    p = tmp_path / "reach.toml"
    p.write_text(text.replace("[gnss]\n", '[gnss]\nsigma_model = { name = "elevation", a_m = 0.5, b_m = 2 }\n'))
    assert load_dataset_spec(p).gnss.sigma_model == SigmaModel("elevation", a_m=0.5, b_m=2.0)
    p.write_text(text.replace("[corrections]", '[gnss.sigma_model]\nname = "elevation-cn0"\nzenith_m = 1.0\n'
                                               '\n[corrections]'))
    assert load_dataset_spec(p).gnss.sigma_model == SigmaModel("elevation-cn0", zenith_m=1.0)


@pytest.mark.parametrize("line, key, words", [
    ('sigma_model = "snr"', "gnss.sigma_model.name", "must be one of receiver, elevation, sigma-epsilon"),
    ('sigma_model = { name = "elevation", a_m = -0.5 }', "gnss.sigma_model.a_m", "must be >= 0, got -0.5"),
    ('sigma_model = { name = "elevation", c_m2hz = 1e4 }', "gnss.sigma_model.c_m2hz",
     "not a parameter of the 'elevation' model"),
    ('sigma_model = { name = "sigma-epsilon", c_m2hz = 0 }', "gnss.sigma_model.c_m2hz", "a zero sigma"),
    ('sigma_model = { a_m = 1.0 }', "gnss.sigma_model.name", "missing"),
    ("sigma_model = 3", "gnss.sigma_model", "a model name or a table"),
])
def test_bad_spec_sigma_model_names_the_key(tmp_path, line, key, words):
    p = _with_gnss_line(tmp_path, SMARTLOC_SPEC, line)
    with pytest.raises(DatasetSpecError, match=words) as ei:
        load_dataset_spec(p)
    assert ei.value.key == key and str(ei.value).startswith(f"{p}: {key}: ") and "\n" not in str(ei.value)


def test_rinex_sigma0_with_another_model_is_refused(tmp_path):
    p = _with_gnss_line(tmp_path, REACH_SPEC, 'sigma_model = "elevation"')                 # sigma0_m = 1.5 too
    with pytest.raises(DatasetSpecError, match="applies to sigma_model 'receiver' only") as ei:
        load_dataset_spec(p)
    assert ei.value.key == "gnss.sigma0_m"


@needs_smartloc
def test_smartloc_replay_applies_the_sigma_model(tmp_path):
    from envs.worlds import make_world
    default = make_world("smartloc-potsdamer-platz", [0], duration_s=20.0)
    g0 = default.gnss
    m = g0.mask
    np.testing.assert_allclose(g0.pr_sigma[m] ** 2, np.round(g0.pr_sigma[m] ** 2), atol=1e-9)  # recorded: 25, 64..
    for name in ("elevation", "sigma-epsilon", "elevation-cn0"):
        w = make_world(_with_gnss_line(tmp_path, SMARTLOC_SPEC, f'sigma_model = "{name}"', f"s-{name}"), [0],
                       duration_s=20.0)
        g = w.gnss
        np.testing.assert_array_equal(g.pr, g0.pr)
        np.testing.assert_array_equal(g.mask, m)
        want = np.sqrt(SigmaModel(name).variance(g.elevation, g.cn0_dbhz))
        np.testing.assert_allclose(g.pr_sigma[m], want[m], rtol=1e-12)
        assert np.all(g.pr_sigma[~m] == 0) and w.scenario.receiver.sigma_model.name == name
    # sigma-epsilon by hand on one channel: C/N0 49 dB-Hz -> sqrt(1.1e4 * 10^-4.9)
    g = make_world(_with_gnss_line(tmp_path, SMARTLOC_SPEC, 'sigma_model = "sigma-epsilon"', "s-one"), [0],
                   duration_s=20.0).gnss
    k = np.argwhere(m[0] & (g.cn0_dbhz[0] == 49.0))[0]
    assert abs(g.pr_sigma[0][tuple(k)] - math.sqrt(1.1e4 * 10 ** -4.9)) < 1e-12


@needs_reach
def test_rinex_replay_applies_the_sigma_model_and_names_a_file_without_cn0(tmp_path, monkeypatch):
    from envs.datasets import dataset_world
    from envs.worlds import make_world
    text = REACH_SPEC.read_text().replace("sigma0_m = 1.5\n", "")
    p = tmp_path / "reach.toml"
    p.write_text(text.replace("[gnss]\n", '[gnss]\nsigma_model = "elevation-cn0"\n'))
    w = make_world(p, [0], duration_s=10.0)
    g, m = w.gnss, w.gnss.mask
    assert m.sum() > 50 and np.all(g.cn0_dbhz[m] > 20)                            # the file's S1C
    want = np.sqrt(SigmaModel("elevation-cn0").variance(g.elevation, g.cn0_dbhz))
    np.testing.assert_allclose(g.pr_sigma[m], want[m], rtol=1e-12)
    base = make_world("instinct-reach-static", [0], duration_s=10.0).gnss
    np.testing.assert_array_equal(g.pr, base.pr)
    np.testing.assert_allclose(base.pr_sigma[m], 1.5 * np.sqrt(1 + 1 / np.sin(np.maximum(base.elevation[m],
                                                                                     MIN_ELEVATION_RAD)) ** 2))
    # a recording without C/N0 (no S1C): one error naming the observation file
    real = dataset_world.prepare_rinex

    def no_cn0(spec):
        rec = real(spec)
        return dataclasses.replace(rec, epochs=dataclasses.replace(rec.epochs, cn0=np.zeros_like(rec.epochs.cn0)))

    monkeypatch.setattr(dataset_world, "prepare_rinex", no_cn0)
    with pytest.raises(ValueError, match=r"reach-m2-01_raw_202306291111\.23O: sigma_model 'elevation-cn0' "
                                         r"needs the C/N0"):
        make_world(p, [0], duration_s=10.0)
