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
    wrote = next(x for x in p.stdout.splitlines() if x.startswith("wrote "))
    for f in ("results.json", "results.md", "results.csv", "cdf_seed000-sim.png", "NOTE.md"):
        assert str(out / f) in wrote, f  # stdout lists every file written
    assert per["kf+onestep"]["paired_vs_reference"]["episodes"] == 3
    for f in ("cdf_seed000-sim.png", "paired_seed000-sim.png", "trajectory_seed000-sim.png"):
        assert (out / f).stat().st_size > 0
    note = (out / "NOTE.md").read_text()
    d = per["kf+onestep"]["paired_vs_reference"]
    assert f"kf+onestep: horizontal RMSE {100 * d['rel_diff']:+.1f}% against `kf`" in note
    # 3 episodes: below the minimum for a CI, the note gives neither a CI nor a verdict nor a goal judgement
    line = next(x for x in note.splitlines() if x.startswith("- `seed000-sim`: kf+onestep:"))
    assert line.endswith("n < 10: no CI; goal +50% not judged (n < 10).") and "95% CI" not in line
    assert "| seed000-sim | kf |" in note


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
    (("--headroom",), "--headroom needs the optimized fixed parameter: add a 'tuned:<tuning.json>'"),
    (("--methods", "kf,oracle-schedule:GnssIns/Nope-v0"), "unknown environment id 'GnssIns/Nope-v0'"),
    (("--methods", "kf,oracle-schedule:GnssIns/SageHusa-v1[m=3]"),
     "unknown option 'm' in 'oracle-schedule:GnssIns/SageHusa-v1[m=3]'; oracle-schedule takes segment_s"),
    (("--methods", "kf,best-per-episode:GnssIns/STKF-v1[segment_s=5]"), "unknown option 'segment_s'"),
    (("--methods", "kf,crossfit-schedule:GnssIns/MASTKF-v1[n=1]"), "bad value '1' for 'n'"),
    (("--methods", "kf,oracle-schedule:GnssIns/SageHusa-v1[segment_s=abc]"), "bad value 'abc' for 'segment_s'"),
    (("--methods", "oracle-schedule:GnssIns/SageHusa-v1,kf"), "is an oracle; the reference must be a method"),
    (("--methods", "kf,oracle-schedule:GnssIns/SageHusa-v1", "--zupt", "shoe"), "use --zupt none or truth"),
    (("--methods", "kf,sage-husa[b=nan]"), "sage-husa[b=nan].b must not be NaN"),
    (("--methods", "kf,sage-husa[b=inf]"), "sage-husa[b=inf].b must lie in (0, 1]"),
    (("--methods", "kf,sage-husa[b=2]"), "sage-husa[b=2].b must lie in (0, 1]"),
    (("--methods", "kf,sage-husa[b=-5]"), "sage-husa[b=-5].b must lie in (0, 1]"),
    (("--methods", "kf,sage-husa[q=1]"), "sage-husa[q=1]: unknown parameter 'q' of 'sage-husa'"),
    (("--methods", "kf[b=0.9]"), "kf[b=0.9]: method 'kf' has no parameters to set"),
    (("--methods", "kf,rule:GnssIns/SageHusa-v1[hold=x]"), "bad value 'x' for 'hold'"),
    (("--methods", "kf,oracle-r:ukf"), "unknown filter method"),
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


def test_paired_verdicts_from_the_minimum_number_of_episodes(tmp_path):
    out = tmp_path / "r"
    p = run_eval("--scenario", "seed000-sim", "--methods", "kf,kf+onestep", "--episodes", "10", "--out", str(out),
                 "--no-plots", "--note", str(out / "NOTE.md"), "--goal", "50")
    assert p.returncode == 0, p.stderr
    d = json.loads((out / "results.json").read_text())["scenarios"]["seed000-sim"]["kf+onestep"]["paired_vs_reference"]
    line = next(x for x in (out / "NOTE.md").read_text().splitlines() if x.startswith("- `seed000-sim`: kf+onestep:"))
    lo, hi = d["diff_rmse_h_ci95_m"]
    assert f"95% CI [{lo:+.2f}, {hi:+.2f}] m" in line and "n < 10" not in line
    assert any(v in line for v in ("lower (the 95% CI", "higher (the 95% CI", "no significant difference"))
    assert ("goal +50% met" in line) == (d["rel_diff"] <= 0.5)


def test_headroom_table_and_json(tmp_path):
    """--headroom: the optimized fixed parameter against the oracles (net of the open-sky placebo), and the share
    of the knob headroom the other methods closed; oracles are labelled as such everywhere."""
    fixed = tmp_path / "fixed" / "tuning.json"
    fixed.parent.mkdir()
    fixed.write_text(json.dumps({"method": "sage-husa", "param": "b", "best": 0.98}))
    for i, b in enumerate((0.95, 0.995)):  # a group of two 'seeds' (pooled row)
        (tmp_path / f"g{i}").mkdir()
        (tmp_path / f"g{i}" / "tuning.json").write_text(json.dumps({"method": "sage-husa", "param": "b", "best": b}))
    knob = "oracle-schedule:GnssIns/SageHusa-v1[segment_s=30,lookahead_s=0,n=3]"
    methods = f"tuned:{fixed},kf,tuned:{tmp_path}/g*/tuning.json,{knob},best-per-episode:GnssIns/SageHusa-v1[n=2]"
    out = tmp_path / "o"
    p = run_eval("--scenario", "seed000-sim", "--scenario", "open-sky", "--episodes", "2", "--methods", methods,
                 "--headroom", "--out", str(out), "--no-plots", "--note", str(out / "NOTE.md"))
    assert p.returncode == 0, p.stderr
    res = json.loads((out / "results.json").read_text())
    h = res["headroom"]
    assert h["min_ci_episodes"] == 10 and h["placebo"] == "open-sky" and h["fixed"] == f"tuned:{fixed}"
    rmse = {s: {m: r["rmse_h_m"] for m, r in per.items()} for s, per in res["scenarios"].items()}
    ko = "oracle: " + knob
    assert res["scenarios"]["seed000-sim"][ko]["oracle"] is True
    hr = {}
    for s in ("seed000-sim", "open-sky"):
        e = h["scenarios"][s]
        assert set(e) == {"note", "fixed", "knob_oracle", "best_hand_designed", "oracles", "methods"}
        assert e["knob_oracle"] == ko and e["fixed"]["label"] == f"tuned:{fixed}"
        # the best hand-designed row: the lowest RMSE of the rows that are not oracles (whatever theirs)
        hand = {m: r for m, r in rmse[s].items() if not m.startswith("oracle")}
        b = e["best_hand_designed"]
        assert b["label"] == min(hand, key=hand.get) and set(b["candidates"]) == set(hand)
        for lab, o in e["oracles"].items():
            R = rmse[s][b["label"]]
            assert o["from_best"]["headroom"] == pytest.approx((R - rmse[s][lab]) / R, rel=1e-9)
            assert o["from_best"]["headroom_ci95"] is None and o["from_best"]["ci_note"] == "n < 10: no CI"
        assert set(e["oracles"]) == {ko, "oracle: best-per-episode:GnssIns/SageHusa-v1[n=2]"}
        o = e["oracles"][ko]
        F, O = rmse[s][f"tuned:{fixed}"], rmse[s][ko]
        assert o["headroom"] == pytest.approx((F - O) / F, rel=1e-9) and o["kind"] == "oracle-schedule"
        assert o["headroom_ci95"] is None and o["ci_note"] == "n < 10: no CI"  # 2 episodes
        hr[s] = o["headroom"]
        assert set(e["methods"]) == {"kf", f"tuned:{tmp_path}/g0/tuning.json", f"tuned:{tmp_path}/g1/tuning.json",
                                     f"tuned:{tmp_path}/g*/tuning.json (pooled over 2 seeds)"}
        assert not any(m.startswith("oracle") for m in e["methods"])
        assert e["methods"][f"tuned:{tmp_path}/g*/tuning.json (pooled over 2 seeds)"]["pooled"] is True
    e = h["scenarios"]["seed000-sim"]
    o = e["oracles"][ko]
    assert o["placebo_headroom"] == pytest.approx(hr["open-sky"]) and o["net_headroom"] == pytest.approx(
        hr["seed000-sim"] - hr["open-sky"])
    F, O = rmse["seed000-sim"][f"tuned:{fixed}"], rmse["seed000-sim"][ko]
    gap = F - O - hr["open-sky"] * F
    for m, r in e["methods"].items():
        assert r["net"] is True and r["gap_m"] == pytest.approx(gap, rel=1e-9)
        if gap > 0:
            assert r["share"] == pytest.approx((F - r["rmse_h_m"]) / gap, rel=1e-9) and r["share_ci95"] is None
        else:
            assert r["share"] is None and "no net headroom" in r["note"]
    assert h["scenarios"]["open-sky"]["note"].startswith("this is the placebo scenario")
    assert h["scenarios"]["open-sky"]["methods"]["kf"]["net"] is False  # on the placebo: the gross headroom
    table = (out / "headroom.md").read_text()  # rows by their short labels (results.json keeps the specs)
    assert "| seed000-sim | oracle: schedule (knob) | 2 |" in table
    assert "| open-sky | optimized fixed: tuned b=0.98 |" in table and str(tmp_path) not in table
    assert "| seed000-sim | tuned (2 seeds) | 2 |" in table  # the pooled row of the g* group
    assert "n < 10: no CI" in table and "- `seed000-sim`: placebo: open-sky" in table
    assert "headroom from the best hand-designed (95% CI)" in table
    import eval as ev
    best = h["scenarios"]["seed000-sim"]["best_hand_designed"]["label"]
    assert f"- `seed000-sim`: best hand-designed method: {ev.method_labels(res, 'seed000-sim')[best]} (RMSE h" in table
    assert table.strip() in p.stdout
    note = (out / "NOTE.md").read_text()
    assert "## Headroom" in note and table.strip() in note


def test_headroom_without_placebo_says_so(tmp_path):
    fixed = tmp_path / "tuning.json"
    fixed.write_text(json.dumps({"method": "sage-husa", "param": "b", "best": 0.98}))
    out = tmp_path / "o"
    p = run_eval("--scenario", "seed000-sim", "--episodes", "2", "--methods",
                 f"tuned:{fixed},kf,crossfit-schedule:GnssIns/SageHusa-v1[segment_s=30,lookahead_s=0,n=2]",
                 "--headroom", "--out", str(out), "--no-plots", "--note", str(out / "NOTE.md"))
    assert p.returncode == 0, p.stderr
    note = (out / "NOTE.md").read_text()
    assert "oracle rows know the truth: they bound what a method could reach, no user could run them" in note
    line = next(x for x in note.splitlines() if x.startswith("- `seed000-sim`: oracle: crossfit schedule: "))
    assert line.endswith("n < 10: no CI.")  # said once above, not on every oracle line
    assert note.splitlines()[2].startswith("- `seed000-sim` (2 episodes, reference `tuned b=0.98` ")  # the verdict
    assert "oracle" not in note.splitlines()[2]  # an oracle is never the best method
    e = json.loads((out / "results.json").read_text())["headroom"]["scenarios"]["seed000-sim"]
    assert e["note"].startswith("placebo not measured") and e["knob_oracle"] is None
    o = e["oracles"]["oracle: crossfit-schedule:GnssIns/SageHusa-v1[segment_s=30,lookahead_s=0,n=2]"]
    assert o["net_headroom"] is None and o["kind"] == "crossfit-schedule"
    assert e["methods"]["kf"]["share"] is None and "no knob oracle" in e["methods"]["kf"]["note"]
    assert "placebo not measured" in (out / "headroom.md").read_text()


def test_oracle_method_specs():
    from agents.methods import OracleMethod, expand_method_spec, is_oracle_label, parse_method_spec
    m = parse_method_spec("oracle-schedule:GnssIns/SageHusa-v1[segment_s=10,lookahead_s=20,n=7]")
    assert isinstance(m, OracleMethod) and (m.kind, m.env_id) == ("oracle-schedule", "GnssIns/SageHusa-v1")
    assert m.options == {"segment_s": 10.0, "lookahead_s": 20.0, "n": 7} and isinstance(m.options["n"], int)
    assert m.label == "oracle: oracle-schedule:GnssIns/SageHusa-v1[segment_s=10,lookahead_s=20,n=7]"
    assert is_oracle_label(m.label) and is_oracle_label("oracle-r") and not is_oracle_label("kf")
    # the brackets are options, not a glob pattern
    [e] = expand_method_spec("best-per-episode:GnssIns/MASTKF-v1[n=3]", "urban")
    assert (e.kind, e.env_id, e.options) == ("best-per-episode", "GnssIns/MASTKF-v1", {"n": 3})
    assert parse_method_spec("crossfit-schedule:GnssIns/STKF-v1").options == {}
    # the knob's oracle on top of fault exclusion: the env's filter method as an option, checked up front
    m = parse_method_spec("oracle-schedule:GnssIns/SageHusa-v1[n=3,method=sage-husa+fde]")
    assert m.options == {"n": 3, "method": "sage-husa+fde"}
    with pytest.raises(ValueError, match="does not take the parameter"):
        parse_method_spec("oracle-schedule:GnssIns/SageHusa-v1[method=kf-fde]")


def test_oracle_r_beats_kf_on_urban_and_refuses_worlds_without_a_truth():
    """oracle-r: kf given the simulator's true per-satellite variance (NLOS bias^2 included) is far below kf on
    urban; NLOS exclusion too; a recording gets the truth-error oracle, a world without either a clear error."""
    import dataclasses

    import numpy as np

    from agents.methods import OracleRMethod, is_oracle_label, parse_method_spec
    from envs.worlds import make_world
    world = make_world("urban", [3, 4, 5, 6], duration_s=120.0)
    rmse = {}
    for spec in ("kf", "oracle-r", "oracle-nlos-excluded", "oracle-r:svd-srkf"):
        m = parse_method_spec(spec)
        h = m.run(world).horizontal_error
        rmse[spec] = float(np.sqrt(np.mean(h ** 2)))
    assert isinstance(parse_method_spec("oracle-r"), OracleRMethod) and is_oracle_label("oracle-nlos-excluded")
    assert rmse["oracle-r"] < 0.7 * rmse["kf"] and rmse["oracle-nlos-excluded"] < rmse["kf"], rmse
    assert abs(rmse["oracle-r:svd-srkf"] / rmse["oracle-r"] - 1) < 1e-6  # the same filter in another form
    # without the simulator's variances the oracle is the real-data one (truth errors: envs.datasets.truth_check)
    recorded = dataclasses.replace(world, gnss=dataclasses.replace(world.gnss, pr_var_true=None, prr_var_true=None))
    assert np.isfinite(parse_method_spec("oracle-r").run(recorded).horizontal_error).all()
    bare = dataclasses.replace(recorded, gnss=dataclasses.replace(recorded.gnss, pr_error_m=None))
    with pytest.raises(ValueError, match="recorded data set"):
        parse_method_spec("oracle-r").run(bare)
    with pytest.raises(ValueError, match="unknown filter method"):
        parse_method_spec("oracle-r:nope")


def test_same_seed_same_results_bytes_apart_from_the_timing_keys(tmp_path):
    """Two runs with the same arguments write results.json files that differ only on the lines of the wall-clock
    keys (eval.TIMING_KEYS, documented in eval.py); the file is strict JSON (no NaN literal) and timing.json
    keeps the timings apart."""
    import math
    texts = []
    for d in ("a", "b"):
        p = run_eval("--scenario", "seed000-sim", "--methods", "kf,sage-husa,stkf", "--episodes", "2", "--seed", "4",
                     "--out", str(tmp_path / d), "--no-plots")
        assert p.returncode == 0, p.stderr
        texts.append((tmp_path / d / "results.json").read_text())
    la, lb = (t.splitlines() for t in texts)
    assert len(la) == len(lb)
    differ = [(x, y) for x, y in zip(la, lb) if x != y]
    timing_keys = ('"filter_time_per_epoch_s"',)
    assert all(any(k in x for k in timing_keys) for x, _ in differ), differ
    strict = json.loads(texts[0], parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    timing = json.loads((tmp_path / "a" / "timing.json").read_text())
    for m, r in strict["scenarios"]["seed000-sim"].items():
        assert timing["scenarios"]["seed000-sim"]["methods"][m]["filter_time_per_epoch_s"] == r["filter_time_per_epoch_s"]
    assert timing["wall_time_s"] > 0 and "filter_time_per_epoch_s" in timing["scenarios"]["seed000-sim"]["methods"]["kf"]
    from envs.json_io import dumps
    assert dumps({"x": [math.nan, math.inf, -math.inf, 1.5]}) == '{"x": [null, null, null, 1.5]}'


def test_skip_missing_leaves_a_method_out_where_it_has_no_file(tmp_path):
    """--skip-missing: a pattern without a file on one scenario gives no row there, says so in results.json
    and the note; without the flag it is a one-line error; the optimized fixed parameter of --headroom and
    the reference are never skipped."""
    import json as _json
    d = tmp_path / "runs" / "urban" / "t0"
    d.mkdir(parents=True)
    (d / "tuning.json").write_text(_json.dumps({"method": "sage-husa", "param": "b", "best": 0.9}))
    tuned = f"tuned:{tmp_path}/runs/{{scenario}}/t*/tuning.json"
    common = ("--scenario", "urban", "--scenario", "open-sky", "--episodes", "1", "--no-plots")
    p = run_eval(*common, "--methods", f"kf,{tuned}", "--out", str(tmp_path / "a"))
    assert p.returncode == 2 and "no file matches" in p.stderr and "Traceback" not in p.stderr
    out = tmp_path / "b"
    p = run_eval(*common, "--methods", f"kf,{tuned}", "--skip-missing", "--out", str(out),
                 "--note", str(out / "NOTE.md"))
    assert p.returncode == 0, p.stderr
    res = _json.loads((out / "results.json").read_text())
    assert set(res["scenarios"]["urban"]) == {"kf", tuned.replace("t*", "t0")}
    assert set(res["scenarios"]["open-sky"]) == {"kf"}
    assert [(k["scenario"], k["method"]) for k in res["config"]["skipped"]] == [("open-sky", tuned)]
    note = (out / "NOTE.md").read_text()
    assert "## Methods not run on every scenario" in note and f"- `open-sky`: `{tuned}`" in note
    p = run_eval(*common, "--methods", f"{tuned},kf", "--skip-missing", "--out", str(tmp_path / "c"))
    assert p.returncode == 2 and "no file matches" in p.stderr
    p = run_eval(*common, "--methods", f"kf,{tuned}", "--skip-missing", "--headroom", "--out", str(tmp_path / "d"))
    assert p.returncode == 2 and "matches no file on 'open-sky'" in p.stderr and "Traceback" not in p.stderr


def _headroom_inputs(rows, E=12, M=20, seed=0):
    """compute_headroom's inputs for one scenario 'urban' from ``rows``: ``[(method object, scale, diverged)]``;
    a method's horizontal errors are ``scale`` times one shared (E, M) draw, so every pooled RMSE ratio (and
    every paired bootstrap resample of it) is the ratio of the scales."""
    import numpy as np

    from envs.episodes import EpisodeLog
    from envs.metrics import summarize
    base = np.random.default_rng(seed).gamma(2.0, 1.0, (E, M))
    curves, plan, summ = {}, [], {}
    for m, scale, div in rows:
        pos = np.zeros((E, M, 3))
        pos[..., 1] = scale * base
        z = np.zeros((E, M))
        log = EpisodeLog(t=np.arange(M, dtype=float), pos_err_ned=pos, vel_err_ned=np.zeros((E, M, 3)), nees_pv=z,
                         nis=z, n_used=z.astype(int), n_sats=z.astype(int), gdop=z, zupt=z.astype(bool),
                         diverged=np.zeros(E, bool) if div is None else np.asarray(div), filter_time_s=1.0)
        curves[m.label] = log
        summ[m.label] = summarize(log)
        plan.append((m.label.removeprefix("oracle: "), [m]))
    return {"scenarios": {"urban": summ}, "seed_groups": {}}, {"urban": curves}, {"urban": plan}, base


def _methods():
    from agents.methods import FilterMethod, OracleMethod, OracleRMethod, PolicyMethod, RuleMethod
    return {"fixed": FilterMethod("tuned:runs/t/tuning.json", "sage-husa", {"b": 0.98}),
            "kf": FilterMethod("kf", "kf"), "fde": FilterMethod("kf-fde", "kf-fde"),
            "vb": FilterMethod("vb-akf", "vb-akf"),
            "rule": RuleMethod("rule:GnssIns/SageHusa-v1", "GnssIns/SageHusa-v1"),
            "ppo": PolicyMethod("ppo:runs/p/model.zip", "ppo", "runs/p/model.zip", None),
            "knob": OracleMethod("oracle: oracle-schedule:GnssIns/SageHusa-v1", "oracle-schedule",
                                 "GnssIns/SageHusa-v1"),
            "oracle-r": OracleRMethod("oracle-r")}


def test_headroom_from_the_best_hand_designed_method():
    """compute_headroom picks the lowest-RMSE row among the methods that are neither oracles nor learned (a
    learned policy and the oracles below it are not picked), reports each oracle's headroom from it, (best -
    oracle) / best, with the analytic value and CI on known errors, and keeps the columns against the fixed
    parameter; format_headroom shows the column and names the method in a note line."""
    import eval as ev
    M = _methods()
    rows = [(M["fixed"], 2.0, None), (M["kf"], 3.0, None), (M["fde"], 1.5, None), (M["vb"], 1.7, None),
            (M["rule"], 1.6, None), (M["ppo"], 1.0, None), (M["knob"], 1.2, None), (M["oracle-r"], 0.5, None)]
    results, curves, plan, _ = _headroom_inputs(rows)
    h = ev.compute_headroom(results, curves, plan, "tuned:runs/t/tuning.json")
    e = h["scenarios"]["urban"]
    b = e["best_hand_designed"]
    assert b["label"] == "kf-fde" and b["rmse_h_m"] == results["scenarios"]["urban"]["kf-fde"]["rmse_h_m"]
    assert set(b["candidates"]) == {"tuned:runs/t/tuning.json", "kf", "kf-fde", "vb-akf", "rule:GnssIns/SageHusa-v1"}
    assert b["episodes"] == 12 and b["diverged"] == 0
    for lab, o_scale in (("oracle: oracle-schedule:GnssIns/SageHusa-v1", 1.2), ("oracle-r", 0.5)):
        o = e["oracles"][lab]
        fb = o["from_best"]
        assert fb["headroom"] == pytest.approx(1 - o_scale / 1.5, rel=1e-12) and fb["episodes"] == 12
        assert fb["headroom_ci95"] == pytest.approx([1 - o_scale / 1.5] * 2, rel=1e-9) and fb["ci_note"] is None
        assert o["headroom"] == pytest.approx(1 - o_scale / 2.0, rel=1e-12)  # today's column: from the fixed row
    assert e["methods"]["ppo:runs/p/model.zip"]["share"] == pytest.approx((2.0 - 1.0) / (2.0 - 1.2), rel=1e-9)
    table = ev.format_headroom(h)
    lines = table.splitlines()
    assert lines[0].endswith("| headroom from the best hand-designed (95% CI) |") and lines[1] == "|" + "---|" * 8
    assert "| urban | oracle-r | 12 |" in table
    assert next(x for x in lines if x.startswith("| urban | oracle-r |")).endswith("| - | +66.7% [+66.7%, +66.7%] |")
    assert "- `urban`: best hand-designed method: kf-fde (RMSE h" in table
    assert "the lowest of 5 hand-designed rows" in table


def test_headroom_from_the_best_below_the_minimum_episodes_and_with_divergences():
    """Below MIN_CI_EPISODES paired episodes: the re-based headroom has its point value but no CI (the tables'
    words); a hand-designed row's diverged episodes are left out of its RMSE (as in the results table) and of
    the paired comparison with the oracle."""
    import numpy as np

    import eval as ev
    from envs.metrics import MIN_CI_EPISODES, no_ci_text
    M = _methods()
    E = MIN_CI_EPISODES
    div = np.zeros(E, bool)
    div[0] = True  # 9 episodes left: below the minimum
    rows = [(M["fixed"], 2.0, None), (M["vb"], 1.5, div), (M["ppo"], 0.9, None), (M["knob"], 1.2, None)]
    results, curves, plan, base = _headroom_inputs(rows, E=E)
    e = ev.compute_headroom(results, curves, plan, "tuned:runs/t/tuning.json")["scenarios"]["urban"]
    b = e["best_hand_designed"]
    assert b["label"] == "vb-akf" and b["diverged"] == 1
    assert b["rmse_h_m"] == pytest.approx(1.5 * np.sqrt(np.mean(base[1:] ** 2)), rel=1e-12)
    o = e["oracles"]["oracle: oracle-schedule:GnssIns/SageHusa-v1"]
    fb = o["from_best"]
    assert fb["episodes"] == E - 1 and fb["headroom"] == pytest.approx(0.2, rel=1e-12)
    assert fb["headroom_ci95"] is None and fb["ci_note"] == no_ci_text()
    assert o["episodes"] == E and o["headroom_ci95"] is not None  # the column against the fixed row: all 10
    table = ev.format_headroom({"placebo": None, "scenarios": {"urban": e}})
    assert "| +20.0% (n < 10: no CI) |" in table and "diverged in 1 of 10 episodes" in table


def test_gap_to_oracle_r_shares_against_the_reference():
    """compute_gap_to_oracle_r: (ref - method) / (ref - oracle-r) with the analytic value and a degenerate CI on
    errors that are scale multiples of one draw, for a method, a seed group's members and their pooled row; the
    reference and the oracles get no row; no oracle-r row, no section; the table shows the share."""
    import eval as ev
    from agents.methods import PolicyMethod
    M = _methods()
    p1 = PolicyMethod("ppo:runs/q/model.zip", "ppo", "runs/q/model.zip", None)
    rows = [(M["vb"], 1.5, None), (M["kf"], 3.0, None), (M["ppo"], 1.0, None), (p1, 1.25, None),
            (M["knob"], 1.2, None), (M["oracle-r"], 0.5, None)]
    results, curves, plan, _ = _headroom_inputs(rows)
    results["config"] = {"reference_labels": {"urban": "vb-akf"}}
    plan["urban"] = [("vb-akf", [M["vb"]]), ("kf", [M["kf"]]), ("ppo:runs/*/model.zip", [M["ppo"], p1]),
                     ("oracle-schedule:GnssIns/SageHusa-v1", [M["knob"]]), ("oracle-r", [M["oracle-r"]])]
    results["seed_groups"] = {"urban": {"ppo:runs/*/model.zip": {"rmse_h_m": 1.0}}}
    g = ev.compute_gap_to_oracle_r(results, curves, plan)["urban"]
    assert g["reference"] == "vb-akf" and g["oracle"] == "oracle-r"
    m = g["methods"]
    assert set(m) == {"kf", "ppo:runs/p/model.zip", "ppo:runs/q/model.zip",
                      "ppo:runs/*/model.zip (pooled over 2 seeds)"}
    for lab, scale in (("kf", 3.0), ("ppo:runs/p/model.zip", 1.0), ("ppo:runs/q/model.zip", 1.25)):
        want = (1.5 - scale) / (1.5 - 0.5)
        assert m[lab]["share"] == pytest.approx(want, rel=1e-9, abs=1e-12)
        assert m[lab]["share_ci95"] == pytest.approx([want, want], rel=1e-6, abs=1e-9)
        assert m[lab]["gap_m"] == pytest.approx(results["scenarios"]["urban"]["vb-akf"]["rmse_h_m"] * 2 / 3, rel=1e-9)
    pooled = m["ppo:runs/*/model.zip (pooled over 2 seeds)"]
    assert pooled["pooled"] and pooled["learned"]  # pooled MSE: the mean of the seeds' squared errors
    assert pooled["share"] == pytest.approx(1.5 - ((1.0 ** 2 + 1.25 ** 2) / 2) ** 0.5, rel=1e-9)
    assert not m["kf"]["learned"]
    table = ev.format_gap_to_oracle_r({"urban": g})
    assert "| urban | ppo:runs/p/model.zip (learned) | 12 |" in table and "+50.0% [+50.0%, +50.0%]" in table
    assert "-150.0%" in table  # kf: three times the reference's gap worse
    del curves["urban"]["oracle-r"]
    assert ev.compute_gap_to_oracle_r(results, curves, plan) == {}
