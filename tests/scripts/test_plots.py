"""plots.py draws what it promises (labels, event windows, outside legends) and agents.provenance's labels."""
import json

import numpy as np
import pytest

import plots
from agents.provenance import describe_training, short_label, short_labels, training_record
from envs.episodes import EpisodeLog
from envs.metrics import summarize
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
    labels = {"kf": "kf", "tuned:x/tuning.json": "tuned b=0.99", "ppo:x/model.zip": "ppo"}
    truth = np.cumsum(np.ones((M, 2)), 0)
    paths = plots.write_plots(tmp_path, "noise-burst", logs, summary, "tuned:x/tuning.json", labels, truth,
                              event_mask(), learned=["ppo:x/model.zip"])
    names = [p.name for p in paths]
    assert names == ["error_vs_time_noise-burst.png", "trajectory_noise-burst.png", "cdf_noise-burst.png",
                     "rmse_bars_noise-burst.png", "actions_noise-burst.png"]
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
    bars = captured["rmse_bars_noise-burst.png"]
    assert [t.get_text() for t in bars.axes[0].get_xticklabels()] == ["kf", "tuned b=0.99", "ppo"]
    assert "no CI" in bars.axes[0].get_title()  # 4 episodes: no error bars


def test_no_actions_plot_without_a_policy(tmp_path):
    logs = {"kf": fake_log(1.0)}
    assert plots.plot_actions("x", logs, tmp_path / "a.png", {"kf": "kf"}) is False
    assert not (tmp_path / "a.png").exists()


def test_short_labels_and_training_records(tmp_path):
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
    assert short_label(tuned, "open-sky") == "tuned (tuning.json)"  # no file for open-sky
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
    assert f"- `urban`: ppo (`{spec}`): horizontal RMSE +10.0%" in note


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
