"""``python -m envs.datasets check`` (issue 12) on both shipped specs and on bad input."""
import pytest

from envs.datasets.check import main
from envs.datasets.errors import shared_data_dir

DATA = shared_data_dir()


@pytest.mark.skipif(not (DATA / "instinct_tckf_static" / "reach-m2-01_raw_202306291111.nav").is_file()
                    or not (DATA / "smartloc" / "Berlin_Potsdamer_Platz_GT.txt").is_file(),
                    reason=f"shared data not found in {DATA} (absent in a fresh clone)")
def test_check_both_shipped_specs(capsys):
    """Measured: Reach 610 epochs / 60.9 s, GPS 9 satellites, SPP horizontal p50 4.1 m, p95 7.5 m against
    the VN-310 static truth (a different antenna); smartLoc 1372 epochs / 282.8 s, GPS 12 + GLONASS 7,
    p50 27.8 m, p95 62.0 m (urban NLOS)."""
    pytest.importorskip("georinex")
    assert main(["check", "instinct-reach-static", "smartloc-potsdamer-platz"]) == 0
    out = capsys.readouterr().out
    reach, smart = out.split("smartloc-potsdamer-platz:")
    assert "epochs: 610 over 60.9 s, GPS time of week 385962.1-386023.0 s" in reach
    assert "satellites used: GPS 9" in reach and "covers 610 of 610 epochs" in reach
    assert "pseudorange rates (Doppler): none" not in reach
    p50, p95 = (float(x.split()[0]) for x in reach.split("horizontal p50 ")[1].split("p95 "))
    assert 1.0 < p50 < 7.0 and p50 < p95 < 12.0
    assert "epochs: 1372 over 282.8 s" in smart and "GPS 12, GLONASS 7" in smart
    assert "pseudorange rates (Doppler): none" in smart
    p50, p95 = (float(x.split()[0]) for x in smart.split("horizontal p50 ")[1].split("p95 "))
    assert 10.0 < p50 < 50.0 and p50 < p95 < 120.0


def test_check_fails_clearly(tmp_path, capsys):
    assert main(["check", str(tmp_path / "none.toml")]) == 1
    assert "none.toml: dataset spec file does not exist" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "b"\n[gnss]\nformat = "rinex"\nobs = "o"\nnav = ["n"]\nsystems = ["R"]\n')
    assert main(["check", str(bad)]) == 1
    assert f"{bad}: gnss.systems: 'R' is not supported" in capsys.readouterr().err
    missing = tmp_path / "missing.toml"
    missing.write_text('name = "m"\n[gnss]\nformat = "rinex"\nobs = "o.23O"\nnav = ["n.nav"]\n'
                       '[truth]\nformat = "static"\nposition_ecef = [4157198.4, 671195.1, 4774772.0]\n')
    assert main(["check", str(missing)]) == 1
    assert "o.23O: recorded-data file does not exist" in capsys.readouterr().err
    assert main(["check", "no-such-set"]) == 1
    assert "neither a dataset spec path" in capsys.readouterr().err


@pytest.mark.skipif(not (DATA / "smartloc" / "Berlin_Potsdamer_Platz_GT.txt").is_file(),
                    reason=f"smartLoc data not found in {DATA} (absent in a fresh clone)")
def test_check_odometry_and_sigma_model(tmp_path, capsys):
    """The odometry spec's summary names the recorded odom3 rows and what is fused; a C/N0 sigma model is named
    and weights the SPP (a different p50 than the recorded variances give)."""
    from envs.datasets.spec import SPEC_DIR
    assert main(["check", "smartloc-potsdamer-platz-odometry"]) == 0
    out = capsys.readouterr().out
    assert "IMU: synthesized from the truth, consumer grade at 100 Hz" in out
    assert ("odometry: recorded odom3: 1372 rows over 282.8 s, covers 1372 of 1372 epochs; fused: speed + NHC + "
            "yaw rate (sigma 0.3 deg/s), speed sigma 0.1 m/s, NHC 0.1 m/s") in out
    assert "pseudorange sigma" not in out                                      # the default: not printed
    p = tmp_path / "s.toml"
    p.write_text((SPEC_DIR / "smartloc-potsdamer-platz.toml").read_text().replace(
        "[gnss]\n", '[gnss]\nsigma_model = "elevation-cn0"\n'))
    assert main(["check", str(p)]) == 0
    out = capsys.readouterr().out
    assert "pseudorange sigma: elevation-cn0 model" in out and "odometry:" not in out
    assert "horizontal p50 27.77 m" not in out
