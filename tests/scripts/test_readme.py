"""The README's front door: short, the two fresh-clone commands, links that resolve, and the generated results
block (scripts/readme_results.py) on a synthetic results.json shaped like eval.py's."""
import importlib.util
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
COMMANDS = [
    "bash scripts/main.sh     # set up; train a small PPO policy; tune the best fixed b; compare with the baselines "
    "-> results/main/",
    "bash scripts/test.sh     # set up; run the test suite",
]
# Notes that a committed script writes (never by hand): a link to one may precede the file; the test then checks
# that the script exists and names the file.
GENERATED = {ROOT / "docs" / "performance.md": "scripts/performance.sh",
             ROOT / "docs" / "headroom-fde.md": "scripts/headroom.sh"}
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _load():
    spec = importlib.util.spec_from_file_location("readme_results", ROOT / "scripts" / "readme_results.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_readme_is_short_and_starts_with_the_two_commands():
    text = README.read_text()
    lines = text.splitlines()
    assert len(lines) <= 220
    for c in COMMANDS:
        assert lines.count(c) == 1, c
    first_block = text.split("```bash\n", 1)[1].split("```", 1)[0].splitlines()
    assert first_block == COMMANDS
    # the first screen in order: what it is, the commands, the results, the env ids
    order = [text.index(COMMANDS[0]), text.index("<!-- results:begin -->"), text.index("- `GnssIns/SageHusa-v1`:")]
    assert order == sorted(order)
    for env_id in ("SageHusa-v1", "STKF-v1", "MASTKF-v1", "SatelliteR-v0", "SatelliteSageHusa-v0"):
        assert f"- `GnssIns/{env_id}`:" in text


@pytest.mark.parametrize("doc", ["README.md", "docs/usage.md", "docs/filters.md", "docs/scenarios.md"])
def test_relative_links_resolve(doc):
    path = ROOT / doc
    for target in LINK.findall(path.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        f = (path.parent / target.split("#", 1)[0]).resolve()
        if f in GENERATED and not f.is_file():
            assert f"docs/{f.name}" in (ROOT / GENERATED[f]).read_text(), f"{GENERATED[f]} does not write {f}"
            continue
        assert f.is_file(), f"{doc}: link {target} names no file"


def _results(episodes=16):
    def metrics(rmse, diff=None):
        r = {"episodes": episodes, "rmse_h_m": rmse, "rmse_3d_m": rmse * 2, "rmse_h_ci95_m": [rmse - 1, rmse + 1],
             "filter_time_per_epoch_s": 1e-4, "diverged": 0}
        if diff is not None:
            r["paired_vs_reference"] = {"diff_rmse_h_m": diff, "diff_rmse_h_ci95_m": [diff - 0.5, diff + 0.5],
                                        "rel_diff": 0.1, "episodes": episodes}
        return r
    scen = {}
    for s, base in (("urban", 10.0), ("open-sky", 1.25)):
        tuned = f"tuned:runs/x/tune-{s}/tuning.json"
        scen[s] = {"kf": metrics(base + 2, 2.0), "kf-igg3": metrics(base - 1, -1.0), tuned: metrics(base),
                   "ppo:runs/x/model.zip": metrics(base + 0.04, 0.04)}
    return {"scenarios": scen, "seed_groups": {},
            "config": {"episodes": episodes, "seed": 3, "methods": ["kf", "kf-igg3", "tuned:runs/x/tune-{scenario}/"
                                                                    "tuning.json", "ppo:runs/x/model.zip"],
                       "reference": "tuned:runs/x/tune-{scenario}/tuning.json",
                       "reference_labels": {s: f"tuned:runs/x/tune-{s}/tuning.json" for s in scen}}}


def _setup(tmp_path, results):
    out = tmp_path / "results"
    out.mkdir()
    (out / "results.json").write_text(json.dumps(results))
    (out / "paired_urban.png").write_bytes(b"\x89PNG fake")
    readme = tmp_path / "README.md"
    head, tail = "# title\n\nbefore the block\n", "\nafter the block\n## more\n"
    readme.write_text(head + "<!-- results:begin -->\nold table\n<!-- results:end -->" + tail)
    return out, readme, head, tail


def test_readme_results_writes_the_block_only(tmp_path):
    mod = _load()
    out, readme, head, tail = _setup(tmp_path, _results())
    assert mod.main([str(out), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert text.startswith(head + "<!-- results:begin -->\n") and text.endswith("<!-- results:end -->" + tail)
    block = text.split("<!-- results:begin -->\n")[1].split("<!-- results:end -->")[0]
    assert "old table" not in block
    assert "`bash scripts/main.sh`" in block and "16 held-out episodes" in block and "seed 3" in block
    rows = {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[2:-1]]
            for ln in block.splitlines() if ln.startswith("| ") and not ln.startswith("| method")}
    assert list(rows) == ["kf", "kf-igg3", "tuned b", "ppo"]
    assert rows["kf"] == ["12.00", "+2.00 [+1.50, +2.50]", "3.25", "+2.00 [+1.50, +2.50]"]
    assert rows["kf-igg3"][0] == "9.00" and rows["kf-igg3"][2] == "0.25"
    assert rows["tuned b"][1] == rows["tuned b"][3] == "reference"
    assert rows["ppo"][1] == "+0.04 [-0.46, +0.54]"
    assert "![urban: each method's paired horizontal RMSE difference" in block
    assert block.rstrip().endswith("](docs/img/main_paired_urban.png)")
    assert (tmp_path / "docs" / "img" / "main_paired_urban.png").read_bytes() == b"\x89PNG fake"
    assert not list(tmp_path.rglob("*.tmp"))
    # a second run gives the same file (only the block is rewritten)
    assert mod.main([str(out), "--readme", str(readme)]) == 0
    assert readme.read_text() == text


def test_readme_results_no_ci_below_ten_episodes(tmp_path):
    mod = _load()
    from envs.metrics import MIN_CI_EPISODES
    assert mod.MIN_CI_EPISODES == MIN_CI_EPISODES
    out, readme, _, _ = _setup(tmp_path, _results(episodes=4))
    assert mod.main([str(out), "--readme", str(readme), "--picture", ""]) == 0
    assert "+2.00 (no CI)" in readme.read_text() and "![" not in readme.read_text()


def test_readme_results_fails_in_one_line(tmp_path, capsys):
    mod = _load()
    out, readme, _, _ = _setup(tmp_path, _results())
    before = readme.read_text()
    assert mod.main([str(tmp_path / "nothing"), "--readme", str(readme)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "results.json is missing" in err
    broken = _results()
    del broken["config"]["seed"]
    (out / "results.json").write_text(json.dumps(broken))
    assert mod.main([str(out), "--readme", str(readme)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "['config']['seed'] is missing" in err
    assert readme.read_text() == before
