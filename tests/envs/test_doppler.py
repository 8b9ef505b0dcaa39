"""Pseudorange rates from RINEX Doppler (issue 12): sign, wavelengths, and the rate against the (static) truth
projected on the line of sight with the satellite velocity and clock drift."""
import numpy as np
import pytest

from earth.ranging import range_and_rate
from earth.wgs84 import C_LIGHT
from envs.datasets.doppler import pseudorange_rate, wavelength
from envs.datasets.errors import shared_data_dir
from envs.datasets.spec import SPEC_DIR, load_dataset_spec

REACH = shared_data_dir() / "instinct_tckf_static"
needs_reach = pytest.mark.skipif(not (REACH / "reach-m2-01_raw_202306291111.nav").is_file(),
                                 reason=f"Reach M2 RINEX files not found in {REACH} (../shared/data is absent)")


def test_wavelengths_and_sign():
    assert wavelength("G", "D1C") == pytest.approx(C_LIGHT / 1575.42e6) == pytest.approx(0.190293672798)
    assert wavelength("E", "D1X") == wavelength("G", "D1C") and wavelength("E", "D7X") == C_LIGHT / 1207.14e6
    assert wavelength("C", "D2I") == C_LIGHT / 1561.098e6 == wavelength("C", "D1I")   # RINEX 3.02 B1I name
    assert wavelength("C", "D1P") == C_LIGHT / 1575.42e6                                 # B1C
    with pytest.raises(ValueError, match="GLONASS"):
        wavelength("R", "D1C")
    # an approaching satellite (positive Doppler) has a shrinking pseudorange; the satellite clock drift adds
    assert pseudorange_rate(1000.0, 0.19, 0.0) == pytest.approx(-190.0)
    assert pseudorange_rate(0.0, 0.19, 1e-9) == pytest.approx(C_LIGHT * 1e-9)


@needs_reach
def test_doppler_rate_matches_the_static_truth_on_the_line_of_sight(tmp_path):
    """Static Reach M2, GPS + Galileo + BeiDou at 1 Hz: prr - rho_dot(truth, v = 0; satellite velocity and
    clock drift from the broadcast ephemeris) is the receiver clock drift, common to all satellites. After
    removing its per-epoch median the residual is receiver noise: measured p95 0.08 (GPS), 0.06 (Galileo),
    0.05 m/s (BeiDou); a sign error or the wrong carrier (B1I vs L1: 0.9 %) would leave metres per second.
    The common part agrees with the drift of the pseudorange clock bias (same receiver clock)."""
    pytest.importorskip("georinex")
    from envs.datasets.dataset_world import prepare_rinex
    from envs.datasets.replay import reference_clock
    text = (SPEC_DIR / "instinct-reach-static.toml").read_text()
    text = text.replace('systems = ["G"]', 'systems = ["G", "E", "C"]').replace('signals = { G = ["C1C"] }', "")
    text = text.replace('name = "instinct-reach-static"', 'name = "reach-gec"').replace(
        "${NAVGYM_DATA_DIR}", str(shared_data_dir())).replace("[gnss]", "[gnss]\ninterval_s = 1.0")
    (tmp_path / "gec.toml").write_text(text)
    rec = prepare_rinex(load_dataset_spec(tmp_path / "gec.toml"))
    ep, tr = rec.epochs, rec.truth
    assert ep.prr is not None and np.all(ep.prr_sigma[ep.mask] > 0) and np.all(ep.prr_sigma[ep.mask] < 1.0)
    r = np.broadcast_to(tr.r_e[0], (ep.n_epochs, 3))
    _, rho_dot, _ = range_and_rate(ep.sat_pos, ep.sat_vel, r, np.zeros_like(r))
    res = np.where(ep.mask, ep.prr - rho_dot, np.nan)
    drift = np.nanmedian(res, axis=1)
    for code in (1, 8, 32):
        m = ep.mask & (ep.system == code)
        assert m.sum() > 200
        assert np.percentile(np.abs((res - drift[:, None])[m]), 95) < 0.2
    assert np.abs(np.abs(rho_dot[ep.mask]).max()) > 300.0               # the check is not trivially small
    _, ref_drift = reference_clock(ep, r)
    assert abs(np.mean(drift) - np.mean(ref_drift)) < 0.5               # measured 97.9 m/s (u-blox TCXO)


@needs_reach
def test_reach_world_carries_pseudorange_rates_and_doppler_off_removes_them(tmp_path):
    pytest.importorskip("georinex")
    from envs.worlds import make_world
    w = make_world("instinct-reach-static", [1, 2])
    g = w.gnss
    assert g.prr is not None and g.prr.shape == g.pr.shape and g.prr_error_mps is not None
    err = g.prr_error_mps[0][g.mask[0]]
    assert np.percentile(np.abs(err), 95) < 0.5                        # drift reference from the code clock
    off = (SPEC_DIR / "instinct-reach-static.toml").read_text().replace("doppler = true", "doppler = false")
    off = off.replace('name = "instinct-reach-static"', 'name = "reach-no-doppler"').replace(
        "${NAVGYM_DATA_DIR}", str(shared_data_dir()))
    (tmp_path / "off.toml").write_text(off)
    w2 = make_world(str(tmp_path / "off.toml"), [1, 2])
    assert w2.gnss.prr is None and np.array_equal(w2.gnss.pr, g.pr)
