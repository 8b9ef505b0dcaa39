"""plots.py draws what it promises (labels, event windows, outside legends) and agents.provenance's labels."""
import json

import numpy as np
import pytest

import plots
from agents.provenance import describe_training, short_label, short_labels, training_record
from envs.episodes import EpisodeLog
from envs.metrics import paired_difference, summarize
from envs.sim.events import NLOS_ZONE, NOISE, OUTAGE

M, B = 60, 4


def fake_log(scale, params=None, seed=0):
    g = np.random.default_rng(seed)
    pos = scale * g.standard_normal((B, M, 3))
    z = np.zeros((B, M))
    return EpisodeLog(t=np.arange(M, dtype=float), pos_err_ned=pos, vel_err_ned=pos.copy(), nees_pv=z, nis=z,
                      n_used=z.astype(int), n_sats=z.astype(int), gdop=z, zupt=z.astype(bool),
                      diverged=np.zeros(B, bool), filter_time_s=0.1, params=params)


def event_mask():
    em = np.zeros((B, M), np.uint16)
    em[:, 10:20] |= NOISE          # every episode: one window
    em[:1, 40:50] |= OUTAGE        # one episode in four: below the shading share
    em[:, :] |= NLOS_ZONE          # the whole time: named, not shaded
    return em


def test_event_windows_share_and_throughout():
    t = np.arange(M, dtype=float)
    wins = {name: (w, thr) for name, w, thr in plots.event_windows(t, event_mask())}
    assert set(wins) == {"NOISE", "NLOS_ZONE"}
    assert wins["NOISE"] == ([(9.5, 19.5)], False)
    assert wins["NLOS_ZONE"][1] is True
    assert plots.event_windows(t, None) == []
    with pytest.raises(ValueError, match="epochs"):
        plots.event_windows(t[:5], event_mask())


@pytest.fixture
def captured(monkeypatch):
    """The figures the plot functions save (kept open for inspection)."""
    figs = {}

    def save(plt, fig, path):
        fig.savefig(path)
        figs[path.name] = fig
    monkeypatch.setattr(plots, "_save", save)
    yield figs
    import matplotlib.pyplot as plt
    plt.close("all")


def _legend_texts(fig):
    out = []
    for ax in fig.axes:
        if ax.get_legend():
            out += [t.get_text() for t in ax.get_legend().get_texts()]
    for leg in fig.legends:
        out += [t.get_text() for t in leg.get_texts()]
    return out


def test_write_plots_axes_labels_events_and_legends(tmp_path, captured):
    b = np.full((B, M), 0.99)
    b[:, 10:20] = 0.5
    logs = {"kf": fake_log(3.0, seed=1), "tuned:x/tuning.json": fake_log(1.0, seed=2),
            "ppo:x/model.zip": fake_log(1.1, params={"b": b}, seed=3)}
    summary = {m: summarize(log) for m, log in logs.items()}
    for m in ("kf", "ppo:x/model.zip"):  # as eval.py's results rows
        summary[m]["paired_vs_reference"] = paired_difference(logs[m], logs["tuned:x/tuning.json"])
    labels = {"kf": "kf", "tuned:x/tuning.json": "tuned b=0.99", "ppo:x/model.zip": "ppo"}
    truth = np.cumsum(np.ones((M, 2)), 0)
    paths = plots.write_plots(tmp_path, "noise-burst", logs, summary, "tuned:x/tuning.json", labels, truth,
                              event_mask(), learned=["ppo:x/model.zip"])
    names = [p.name for p in paths]
    assert names == ["error_vs_time_noise-burst.png", "trajectory_noise-burst.png", "cdf_noise-burst.png",
                     "paired_noise-burst.png", "actions_noise-burst.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    fig = captured["error_vs_time_noise-burst.png"]
    top, bottom = fig.axes
    assert top.get_ylabel() == "horizontal error [m]" and bottom.get_xlabel() == "time [s]"
    assert bottom.get_ylabel() == "minus tuned b=0.99 [m]"
    texts = _legend_texts(fig)
    for want in ("kf", "ppo", "tuned b=0.99 (reference)", "tuned b=0.99: 10-90% of episodes", "noise burst",
                 "urban zone (NLOS) (throughout)", "ppo: 10-90% of episodes"):
        assert want in texts, (want, texts)
    assert "GNSS outage" not in texts  # one episode in four: not shaded
    # only the reference has a band on the top panel, and the legend sits outside the axes
    assert len(top.collections) == 1
    assert top.get_legend().get_bbox_to_anchor().x0 > top.get_window_extent().x1
    # the noise window is shaded on both panels
    spans = [p for p in top.patches if p.get_facecolor()[:3] != (1.0, 1.0, 1.0)]
    assert len(spans) == 1
    traj = captured["trajectory_noise-burst.png"]
    assert [a.get_xlabel() for a in traj.axes] == ["east [m]", "east error [m]"]
    assert traj.axes[0].get_aspect() == 1.0
    # truth, the reference and the two focus methods (the learned one first)
    tt = _legend_texts(traj)
    assert {"truth", "noise burst", "tuned b=0.99 (reference)", "ppo", "kf"} <= set(tt)
    act = captured["actions_noise-burst.png"]
    assert act.axes[0].get_ylabel() == "b" and act.axes[0].get_xlabel() == "time [s]"
    med = next(ln for ln in act.axes[0].lines if ln.get_label() == "ppo: median").get_ydata()
    assert med[15] == pytest.approx(0.5) and med[30] == pytest.approx(0.99)
    paired = captured["paired_noise-burst.png"]
    assert [t.get_text() for t in paired.axes[0].get_yticklabels()] == [
        "tuned b=0.99 (reference)", "kf (n < 10: no CI)", "ppo (n < 10: no CI)"]  # 4 episodes: no CI bars
    assert "left is better" in captured["cdf_noise-burst.png"].axes[0].get_title()
    for name, f in captured.items():  # plain decimals on every axis, log ones too (no 3x10^-1)
        f.canvas.draw()
        ticks = [t.get_text() for a in f.axes for t in (*a.get_xticklabels(), *a.get_yticklabels(),
                                                        *a.get_xticklabels(minor=True), *a.get_yticklabels(minor=True))]
        assert not any("$" in t or "e-" in t or "\u00d7" in t for t in ticks), (name, ticks)


def test_no_actions_plot_without_a_policy(tmp_path):
    logs = {"kf": fake_log(1.0)}
    assert plots.plot_actions("x", logs, tmp_path / "a.png", {"kf": "kf"}) is False
    assert not (tmp_path / "a.png").exists()


def test_short_labels_and_training_records(tmp_path, monkeypatch):
    (tmp_path / "urban").mkdir()
    (tmp_path / "urban" / "tuning.json").write_text(json.dumps({
        "env": "GnssIns/SageHusa-v1", "env_kwargs": {"scenario": "urban", "episode_length_s": 300},
        "method": "sage-husa", "param": "b", "best": 0.94444, "grid": [0.3, 0.9999], "train_seeds": [1, 2, 3]}))
    for s in (0, 1):
        d = tmp_path / f"ppo-s{s}"
        d.mkdir()
        (d / "config.json").write_text(json.dumps({"env": "GnssIns/SageHusa-v1", "algo": "ppo", "seed": s,
                                                   "env_kwargs": {"episode_length_s": 60.0},
                                                   "n_timesteps": 24576, "n_envs": 8}))
    tuned = f"tuned:{tmp_path}/{{scenario}}/tuning.json"
    assert short_label(tuned, "urban") == "tuned b=0.944"
    assert short_label(tuned, "open-sky") == "tuned (.../open-sky)"  # no file there: its folder, cut at the left
    (tmp_path / "edge").mkdir()
    (tmp_path / "edge" / "tuning.json").write_text(json.dumps({"param": "b", "best": 0.9999}))
    assert short_label(tuned, "edge") == "tuned b=0.9999"  # not 'b=1', which would mean no forgetting
    monkeypatch.chdir(tmp_path)  # a relative path no run has written (a checkout's own runs/main may hold one)
    assert short_label("tuned:runs/main/tune-{scenario}/tuning.json", "urban") == "tuned (runs/main/tune-urban)"
    assert short_label("ppo:a/model.zip", "urban", n_seeds=3) == "ppo (3 seeds)"
    assert short_label("oracle: oracle-schedule:GnssIns/SageHusa-v1[n=7]", "urban") == "oracle: schedule"
    assert short_label("oracle-r", "urban") == "oracle: true R"
    assert short_label("rule:GnssIns/SageHusa-v1[b_low=0.5]", "urban") == "rule b_low=0.5"
    assert short_label("sage-husa[b=0.995]", "urban") == "sage-husa[b=0.995]"
    assert len(short_label("svd-asrkf+onestep[zupt=lstm,zupt_weights=/very/long/path.pt]", "x")) <= 28
    members = [f"ppo:{tmp_path}/ppo-s{s}/model.zip" for s in (0, 1)]
    lab = short_labels(["kf", tuned, *members], "urban")
    assert lab == {"kf": "kf", tuned: "tuned b=0.944", members[0]: "ppo ppo-s0", members[1]: "ppo ppo-s1"}
    assert len(set(short_labels(["a/x:1", "a/x:1 "], "u").values())) == 2  # collisions made distinct
    rt = training_record(tuned, "urban")
    assert (rt["scenario"], rt["episode_length_s"], rt["episodes"], rt["best"]) == ("urban", 300.0, 3, 0.94444)
    rp = [training_record(m, "urban") for m in members]
    # the env's default scenario where the kwargs name none
    assert rp[0]["scenario"] == "noise-burst" and rp[0]["episode_length_s"] == 60.0 and rp[1]["seed"] == 1
    assert describe_training(rp) == "trained on noise-burst, 60 s episodes, 24576 steps, seeds 0, 1"
    assert describe_training([rt]) == "tuned on urban, 300 s episodes, 3 training episodes per value"
    assert training_record("kf", "urban") is None and training_record(f"ppo:{tmp_path}/none/m.zip", "u") is None


def test_table_says_no_ci_below_the_minimum():
    import eval
    from envs.metrics import MIN_CI_EPISODES
    for n in (3, MIN_CI_EPISODES):
        row = {"episodes": n, "rmse_h_m": 1.0, "rmse_h_ci95_m": [0.9, 1.1], "rmse_3d_m": 1.2, "p95_h_m": 1.5,
               "max_h_m": 2.0, "filter_time_per_epoch_s": 1e-3, "diverged": 0}
        other = dict(row, paired_vs_reference={"episodes": n, "diff_rmse_h_m": 0.1, "diff_rmse_h_ci95_m": [0.05, 0.15],
                                               "rel_diff": 0.1})
        res = {"config": {"reference": "kf"}, "scenarios": {"urban": {"kf": row, "stkf": other}}}
        lines = eval.format_table(res).splitlines()
        kf, stkf = lines[2], lines[3]
        if n < MIN_CI_EPISODES:
            assert "0.90-1.10" not in kf and "n < 10: no CI" in kf
            assert "[+0.05, +0.15]" not in stkf and "+0.10 (+10.0%; n < 10: no CI)" in stkf
        else:
            assert "0.90-1.10" in kf and "+0.10 [+0.05, +0.15] (+10.0%)" in stkf and "no CI" not in stkf


def test_training_notes_state_and_warn(tmp_path):
    from agents.provenance import training_notes
    d = tmp_path / "p"
    d.mkdir()
    (d / "config.json").write_text(json.dumps({"env": "GnssIns/SageHusa-v1", "algo": "ppo", "seed": 0,
                                               "env_kwargs": {"episode_length_s": 60.0}, "n_timesteps": 24576}))
    spec = f"ppo:{d}/model.zip"
    notes = training_notes({"noise-burst": ["kf", spec], "urban": ["kf", spec]},
                           {"noise-burst": 300.0, "urban": 300.0})
    assert len(notes) == 2  # kf is not trained; one item per distinct warning
    nb = next(x for x in notes if "`noise-burst`" in x)
    assert nb.startswith(f"- ppo (`{spec}`): trained on noise-burst, 60 s episodes, 24576 steps, seed 0")
    assert "evaluated on `noise-burst` (300 s episodes)" in nb and "(episodes of 60 s)" in nb
    assert "trained on noise-burst; episodes of 60 s" in next(x for x in notes if "`urban`" in x)
    same = training_notes({"noise-burst": [spec]}, {"noise-burst": 60.0})
    assert "outside its training conditions" not in same[0]
    missing = training_notes({"urban": [f"tuned:{tmp_path}/none.json"]})
    assert "no training record found" in missing[0]


def test_note_has_the_training_section(tmp_path):
    import eval
    d = tmp_path / "p"
    d.mkdir()
    (d / "config.json").write_text(json.dumps({"env": "GnssIns/SageHusa-v1", "algo": "ppo", "seed": 2,
                                               "env_kwargs": {"episode_length_s": 60.0}, "n_timesteps": 512}))
    spec = f"ppo:{d}/model.zip"
    row = {"episodes": 3, "rmse_h_m": 1.0, "rmse_h_ci95_m": [0.9, 1.1], "rmse_3d_m": 1.2, "p95_h_m": 1.5,
           "max_h_m": 2.0, "filter_time_per_epoch_s": 1e-3, "diverged": 0}
    pol = dict(row, paired_vs_reference={"episodes": 3, "diff_rmse_h_m": 0.1, "diff_rmse_h_ci95_m": [0.0, 0.2],
                                         "rel_diff": 0.1})
    res = {"config": {"reference": "kf", "episodes": 3, "seed": 0, "dtype": "float64", "methods": ["kf", spec],
                      "episode_length_s": {"urban": 300.0}},
           "scenarios": {"urban": {"kf": row, spec: pol}}}
    eval.write_note(res, tmp_path / "NOTE.md", tmp_path, "x")
    note = (tmp_path / "NOTE.md").read_text()
    assert "## What the tuned and learned methods were trained on" in note
    assert f"- ppo (`{spec}`): trained on noise-burst, 60 s episodes, 512 steps, seed 2; evaluated on `urban`" in note
    # the opening verdict, the short labels keyed to the full spec, the reading by short label
    assert note.startswith("# navgym results\n\n- `urban` (3 episodes, reference `kf` 1.00 m): no verdict below 10 "
                           "episodes (lowest RMSE: the reference; the closest: `ppo`, +0.10 m, +10.0%; no CI).\n")
    assert f"\n- ppo: `{spec}`\n" in note and "| urban | ppo | 3 |" in note and f"| urban | {spec} |" not in note
    assert "- `urban`: ppo: horizontal RMSE +10.0% against `kf` (+0.10 m; reference 1.00 m): n < 10: no CI." in note
    assert "pooled row" not in note and "oracle" not in note  # no sentence for what the run does not have


def test_eval_writes_the_plots_of_a_recording_which_has_no_event_mask(tmp_path):
    """A replayed recording carries no simulator event mask (None): eval.py draws its plots without shading
    instead of failing in the plotting step (it did: np.concatenate of [None])."""
    from envs.datasets.errors import shared_data_dir
    reach = shared_data_dir() / "instinct_tckf_static"
    if not reach.is_dir():
        pytest.skip(f"Reach RINEX data not found in {reach} (../shared/data is absent in a fresh clone)")
    import eval as ev
    out = tmp_path / "r"
    ev.main(["--scenario", "instinct-reach-static", "--methods", "kf,sage-husa", "--episodes", "2",
             "--out", str(out)])
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert "error_vs_time_instinct-reach-static.png" in pngs and "trajectory_instinct-reach-static.png" in pngs


def _row(d, lo, hi, n=12, diverged=0, ref_rmse=2.0):
    return {"rmse_h_m": ref_rmse + d, "episodes": n, "diverged": diverged,
            "paired_vs_reference": {"diff_rmse_h_m": d, "diff_rmse_h_ci95_m": [lo, hi], "rel_diff": d / ref_rmse,
                                    "episodes": n - diverged}}


def test_paired_plot_draws_each_difference_its_ci_and_verdict(tmp_path, captured):
    """The paired-difference plot: a point at each method's difference, a bar over its 95% CI coloured by the
    verdict (green lower, red higher, grey not significant), a hollow point without a bar below 10 episodes
    (labelled so), oracles as diamonds, the reference on top at 0, the numbers in the right-hand column."""
    from matplotlib.colors import to_hex
    ref = "tuned:r/{scenario}/tuning.json"
    rows = {ref: {"rmse_h_m": 2.0, "episodes": 12, "diverged": 0}, "kf": _row(0.8, 0.5, 1.2),
            "sage-husa": _row(-0.3, -0.5, -0.1), "stkf": _row(0.05, -0.1, 0.2, diverged=2),
            "ppo:m.zip": _row(-0.1, -0.3, 0.1, n=6), "oracle: oracle-schedule:X": _row(-0.7, -0.9, -0.5)}
    labels = {ref: "tuned b=0.944", "kf": "kf", "sage-husa": "sage-husa", "stkf": "stkf", "ppo:m.zip": "ppo",
              "oracle: oracle-schedule:X": "oracle: schedule"}
    verdicts = plots.plot_paired("urban", rows, tmp_path / "p.png", ref, labels)
    assert verdicts == {"kf": "higher", "sage-husa": "lower", "stkf": "not significant", "ppo:m.zip": "no CI",
                        "oracle: oracle-schedule:X": "lower"}
    fig = captured["p.png"]
    ax, right = fig.axes
    assert [t.get_text() for t in ax.get_yticklabels()] == [
        "tuned b=0.944 (reference)", "kf", "sage-husa", "stkf (2 diverged)", "ppo (n < 10: no CI)",
        "oracle: schedule"]
    assert [t.get_text() for t in right.get_yticklabels()] == [
        "RMSE 2.00 m", "+0.80 m [+0.50, +1.20] (+40.0%)", "-0.30 m [-0.50, -0.10] (-15.0%)",
        "+0.05 m [-0.10, +0.20] (+2.5%)", "-0.10 m (-5.0%)", "-0.70 m [-0.90, -0.50] (-35.0%)"]
    points = {int(ln.get_ydata()[0]): ln for ln in ax.lines if len(ln.get_xdata()) == 1 and ln.get_marker() != "*"}
    bars = {int(ln.get_ydata()[0]): ln for ln in ax.lines if len(ln.get_xdata()) == 2 and ln.get_ydata()[0] > 0}
    want = {1: (0.8, [0.5, 1.2], "tab:red"), 2: (-0.3, [-0.5, -0.1], "tab:green"),
            3: (0.05, [-0.1, 0.2], "tab:gray"), 5: (-0.7, [-0.9, -0.5], "tab:green")}
    for y, (d, ci, color) in want.items():
        assert points[y].get_xdata()[0] == d and list(bars[y].get_xdata()) == ci
        assert to_hex(points[y].get_color()) == to_hex(bars[y].get_color()) == to_hex(color)
    assert 4 not in bars and points[4].get_xdata()[0] == -0.1 and points[4].get_markerfacecolor() == "white"
    assert points[5].get_marker() == "D" and points[1].get_marker() == "o"
    star = next(ln for ln in ax.lines if ln.get_marker() == "*")
    assert (star.get_xdata()[0], star.get_ydata()[0]) == (0.0, 0)
    texts = _legend_texts(fig)
    for want_text in ("lower RMSE than the reference (95% CI below 0)", "higher RMSE than the reference (95% CI above 0)",
                      "no significant difference (95% CI includes 0)", "fewer than 10 episodes: no CI, no verdict"):
        assert want_text in texts
    assert any(t.startswith("oracle") for t in texts)
    assert ax.get_ylim()[0] > ax.get_ylim()[1]  # the reference on top


def test_trajectory_zooms_on_the_epoch_where_the_estimates_differ_most(tmp_path, captured):
    ref, other = fake_log(0.3, seed=1), fake_log(0.3, seed=1)
    other.pos_err_ned[0, 30, :2] += [3.0, 4.0]  # 5 m from the reference at epoch 30 of episode 0
    logs = {"kf": ref, "sage-husa": other}
    assert plots.zoom_epoch(logs, ["kf", "sage-husa"], "kf") == (30, pytest.approx(5.0))
    early = fake_log(0.3, seed=1)
    early.pos_err_ned[0, 2, :2] += [30.0, 40.0]  # larger, but inside the initial convergence: not the zoom
    early.pos_err_ned[0, 30, :2] += [3.0, 4.0]
    assert plots.zoom_epoch({"kf": ref, "sage-husa": early}, ["kf", "sage-husa"], "kf") == (30, pytest.approx(5.0))
    truth = np.cumsum(np.full((M, 2), 20.0), 0)  # 20 m between epochs: a km-scale track
    plots.plot_trajectory("urban", logs, truth, tmp_path / "t.png", "kf", {"kf": "kf", "sage-husa": "sage-husa"},
                          focus=["sage-husa"])
    ax = captured["t.png"].axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert (x0 + x1) / 2 == pytest.approx(truth[30, 1]) and (y0 + y1) / 2 == pytest.approx(truth[30, 0])
    assert 5.0 < x1 - x0 < 40.0  # the estimates' scale, not the track's (1.2 km)
    assert "t = 30.0 s" in ax.get_title()


@pytest.mark.parametrize("diffs, n, want", [
    ({"sage-husa": (-0.3, -0.5, -0.1), "stkf": (0.1, 0.0, 0.2)}, 12,
     "best is `sage-husa`, -0.30 m, -15.0% against the reference (95% CI [-0.50, -0.10] m): significantly lower."),
    ({"sage-husa": (-0.1, -0.3, 0.1), "stkf": (0.1, 0.0, 0.2)}, 12,
     "no method is significantly better than the reference (lowest RMSE: `sage-husa`, -0.10 m, -5.0%, "
     "95% CI [-0.30, +0.10] m)."),
    ({"sage-husa": (0.3, 0.1, 0.5), "stkf": (0.1, 0.05, 0.2)}, 12,
     "the reference is best (the closest: `stkf`, +0.10 m, +5.0%, 95% CI [+0.05, +0.20] m)."),
    ({"sage-husa": (-0.3, -0.5, -0.1), "stkf": (0.1, 0.0, 0.2)}, 4,
     "no verdict below 10 episodes (lowest RMSE: `sage-husa`, -0.30 m, -15.0% against the reference; no CI)."),
])
def test_the_note_opens_with_one_verdict_per_scenario(diffs, n, want):
    """The best method a user could run against the reference, with the CI, or no verdict below 10 episodes;
    an oracle is never the best method (it knows the truth)."""
    import eval
    rows = {"kf": {"rmse_h_m": 2.0, "episodes": n, "diverged": 0},
            "oracle-r": _row(-1.5, -1.7, -1.3, n=n)}
    rows.update({m: _row(*v, n=n) for m, v in diffs.items()})
    res = {"config": {"reference": "kf", "episodes": n}, "scenarios": {"urban": rows}}
    assert eval.verdict_sentence(res, "urban") == f"`urban` ({n} episodes, reference `kf` 2.00 m): {want}"


def test_tables_show_short_labels_and_results_csv_keeps_the_spec(tmp_path):
    import csv
    import eval
    d = tmp_path / "urban"
    d.mkdir()
    (d / "tuning.json").write_text(json.dumps({"param": "b", "best": 0.94444, "method": "sage-husa"}))
    tuned = f"tuned:{tmp_path}/{{scenario}}/tuning.json"
    members = [f"ppo:{tmp_path}/p-s{s}/model.zip" for s in (0, 1)]
    base = {"rmse_h_ci95_m": [0.9, 1.1], "rmse_3d_m": 1.2, "p95_h_m": 1.5, "max_h_m": 2.0,
            "filter_time_per_epoch_s": 1e-3}
    rows = {tuned: {**base, "rmse_h_m": 2.0, "episodes": 12, "diverged": 0},
            **{m: {**base, **_row(0.1 * (i + 1), 0.0, 0.3)} for i, m in enumerate(members)}}
    group = {**base, **_row(0.15, 0.05, 0.25), "seeds": 2, "members": members, "rmse_h_per_seed_m": [2.1, 2.2]}
    spec = f"ppo:{tmp_path}/p-s*/model.zip"
    res = {"config": {"reference": tuned, "episodes": 12, "reference_labels": {"urban": tuned}},
           "scenarios": {"urban": rows}, "seed_groups": {"urban": {spec: group}}}
    table = eval.format_table(res)
    assert "| urban | tuned b=0.944 | 12 |" in table and "| urban | ppo p-s0 | 12 |" in table
    assert "| urban | ppo (2 seeds), pooled (per seed 2.10-2.20 m) | 12 |" in table and str(tmp_path) not in table
    eval.write_csv(res, tmp_path / "r.csv")
    got = [(r["method"], r["label"]) for r in csv.DictReader(open(tmp_path / "r.csv"))]
    assert got == [(tuned, "tuned b=0.944"), (members[0], "ppo p-s0"), (members[1], "ppo p-s1"),
                   (f"{spec} (pooled over 2 seeds)", "ppo (2 seeds)")]
    # the note reads the pooled row and opens with its verdict
    assert eval.verdict_sentence(res, "urban").endswith(
        "the reference is best (the closest: `ppo (2 seeds)`, +0.15 m, +7.5%, 95% CI [+0.05, +0.25] m).")
