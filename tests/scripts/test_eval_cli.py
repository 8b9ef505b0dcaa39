"""eval.py honours the DESIGN.md section 4 contract: CLI, results.json schema, pairing, clear errors."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def run_eval(*args, cwd=ROOT):
    return subprocess.run([sys.executable, str(ROOT / "eval.py"), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def test_results_json_schema_and_outputs(tmp_path):
    out = tmp_path / "r"
    p = run_eval("--scenario", "seed000-sim", "--methods", "kf,kf+onestep", "--episodes", "3", "--seed", "7",
                 "--out", str(out), "--note", str(out / "NOTE.md"), "--goal", "-20", "--goal", "seed000-sim=50")
    assert p.returncode == 0, p.stderr
    res = json.loads((out / "results.json").read_text())
    per = res["scenarios"]["seed000-sim"]
    assert set(per) == {"kf", "kf+onestep"}
    for m, r in per.items():
        r = dict(r)
        r.pop("paired_vs_reference", None)
        assert r["episodes"] == 3
        for k in ("rmse_h_m", "rmse_3d_m", "max_h_m", "p95_h_m", "filter_time_per_epoch_s"):
            assert isinstance(r[k], float) and r[k] >= 0
        lo, hi = r["rmse_h_ci95_m"]
        assert lo <= r["rmse_h_m"] * 1.0001 and r["rmse_h_m"] <= hi * 1.0001 or lo <= hi
        assert isinstance(r["diverged"], int)
        assert r["rmse_h_m"] <= r["rmse_3d_m"] + 1e-12 and r["p95_h_m"] <= r["max_h_m"] + 1e-12
    for f in ("results.csv", "results.md", "error_vs_time_seed000-sim.png"):
        assert (out / f).stat().st_size > 0
    assert "| seed000-sim | kf |" in p.stdout
    assert per["kf+onestep"]["paired_vs_reference"]["episodes"] == 3
    for f in ("cdf_seed000-sim.png", "rmse_bars_seed000-sim.png", "trajectory_seed000-sim.png"):
        assert (out / f).stat().st_size > 0
    note = (out / "NOTE.md").read_text()
    d = per["kf+onestep"]["paired_vs_reference"]
    assert f"kf+onestep: horizontal RMSE {100 * d['rel_diff']:+.1f}% against `kf`" in note
    assert ("goal +50% met" in note) == (d["rel_diff"] <= 0.5) and "| seed000-sim | kf |" in note  # scenario's own


def test_pairing_same_seed_same_result(tmp_path):
    a = run_eval("--scenario", "seed000-sim", "--methods", "kf", "--episodes", "2", "--seed", "3", "--out",
                 str(tmp_path / "a"), "--no-plots")
    b = run_eval("--scenario", "seed000-sim", "--methods", "kf", "--episodes", "2", "--seed", "3", "--out",
                 str(tmp_path / "b"), "--no-plots", "--batch-size", "1")
    assert a.returncode == 0 and b.returncode == 0
    ra = json.loads((tmp_path / "a" / "results.json").read_text())["scenarios"]["seed000-sim"]["kf"]
    rb = json.loads((tmp_path / "b" / "results.json").read_text())["scenarios"]["seed000-sim"]["kf"]
    for k in ("rmse_h_m", "max_h_m", "p95_h_m"):
        assert ra[k] == pytest.approx(rb[k], rel=1e-9)


@pytest.mark.parametrize("args, msg", [
    (("--scenario", "mars"), "unknown scenario"),
    (("--methods", "kf,ukf"), "unknown filter method"),
    (("--episodes", "0"), "--episodes"),
    (("--seed", "5000"), "--seed"),
    (("--zupt", "glrt"), "--zupt must be one of"),
    (("--goal", "urban=lots"), "--goal expects"),
    (("--methods", "kf,kf[zupt=glrt]"), "kf[zupt=glrt]: zupt must be one of"),
    (("--methods", "kf[zupt=lstm,zupt_weights=/nonexistent/w.pt]"), "weights file '/nonexistent/w.pt'"),
])
def test_cli_errors_are_one_line_exit_2(tmp_path, args, msg):
    p = run_eval(*args, "--out", str(tmp_path))
    assert p.returncode == 2
    assert msg in p.stderr and "Traceback" not in p.stderr


def test_method_specs_with_zupt_aiding():
    from agents.methods import parse_method_spec
    m = parse_method_spec("sage-husa[b=0.99,zupt=shoe]")
    assert (m.method, m.params, m.zupt, m.zupt_weights) == ("sage-husa", {"b": 0.99}, "shoe", None)
    m = parse_method_spec("kf[zupt=truth]")
    assert (m.method, m.params, m.zupt) == ("kf", {}, "truth")
    assert parse_method_spec("kf").zupt is None  # eval.py's --zupt applies


def test_scenario_placeholder_and_seed_patterns(tmp_path):
    """'{scenario}' picks a file per scenario; a glob gives one method per file, labelled with the placeholder."""
    import json as _json
    from agents.methods import expand_method_spec
    for scen, b in (("urban", 0.95), ("open-sky", 0.99)):
        for s in range(3):
            d = tmp_path / scen / f"t{s}"
            d.mkdir(parents=True)
            (d / "tuning.json").write_text(_json.dumps({"method": "sage-husa", "param": "b", "best": b - 0.01 * s}))
    ms = expand_method_spec(f"tuned:{tmp_path}/{{scenario}}/t*/tuning.json", "urban")
    assert [m.params["b"] for m in ms] == pytest.approx([0.95, 0.94, 0.93])
    assert [m.label for m in ms] == [f"tuned:{tmp_path}/{{scenario}}/t{s}/tuning.json" for s in range(3)]
    one = expand_method_spec(f"tuned:{tmp_path}/{{scenario}}/t0/tuning.json", "open-sky")
    assert len(one) == 1 and one[0].params["b"] == pytest.approx(0.99)
    with pytest.raises(FileNotFoundError, match="no file matches"):
        expand_method_spec(f"tuned:{tmp_path}/{{scenario}}/x*/tuning.json", "urban")
    p = run_eval("--scenario", "urban", "--methods", f"kf,tuned:{tmp_path}/{{scenario}}/t*/tuning.json",
                 "--reference", f"tuned:{tmp_path}/{{scenario}}/t*/tuning.json", "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "must be one method" in p.stderr and "Traceback" not in p.stderr
