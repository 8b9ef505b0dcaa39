"""agents.channel_diagnostics: a per-satellite method's actions scored channel by channel against the truth."""
import math

import numpy as np
import pytest

from agents import channel_diagnostics as cd
from agents.learned_r import collect_channel_data, heldout_metrics


class _Const:
    def __init__(self, a):
        self.a, self.rows = a, None

    def reset(self, B):
        self.rows = B

    def act(self, obs):
        return np.full((obs.shape[0], 16), self.a)


def test_collect_records_the_policy_actions():
    """The policy acts on every row (reset to the batch), its clipped actions are recorded per sample, and a
    constant action scores a blind AUC of exactly 0.5 with the same inflation on both classes."""
    pol = _Const(1.5)  # clipped to 1: x10^4
    d = collect_channel_data("urban-smartloc", [880_000, 880_001], 20.0, policy=pol, env_kwargs={"method": "kf"})
    assert pol.rows == 2 and d["action"].shape == d["nlos"].shape and np.all(d["action"] == 1.0)
    assert d["nlos"].any() and (~d["nlos"]).any()
    m = heldout_metrics(math.log(10) * 2 * (d["action"] + 1), d)
    assert m["auc_nlos"] == pytest.approx(0.5) and m["mean_log10_inflation"] == pytest.approx(4.0)
    assert "action" not in collect_channel_data("urban-smartloc", [880_000], 5.0)


def test_learned_r_separates_and_table():
    """The shipped learned-r, closed loop on 2 short held-out worlds, separates NLOS better than chance and
    inflates NLOS channels more than clean ones; the table shows both."""
    m = cd.method_diagnostics("learned-r:pretrained/learned-r/model.pt", episodes=2, episode_length_s=30.0)
    assert m["auc_nlos"] > 0.6 and m["mean_log10_inflation_nlos"] > m["mean_log10_inflation_los"]
    assert m["env_kwargs"] == {"method": "kf"} and m["episodes"] == 2
    lines = cd.table({"learned-r": m})
    assert lines[2].startswith("| learned-r | kf | ")


def test_bad_method_spec():
    with pytest.raises(ValueError, match="expected 'ppo:<model.zip>' or 'learned-r:<model.pt>'"):
        cd.load_method("kf-huber")
