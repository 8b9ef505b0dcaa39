"""Write the main job's results into README.md: the block between the results markers and one picture.

    python scripts/readme_results.py [RESULTS_DIR]      (default: results/main, written by scripts/main.sh)

Reads RESULTS_DIR/results.json (eval.py's output) and replaces the lines between ``<!-- results:begin -->``
and ``<!-- results:end -->`` in README.md with a caption (the command, episodes, seed), a Markdown table (rows:
the methods with short labels; per scenario: the horizontal RMSE and the paired difference to the reference
with its 95% bootstrap CI) and the picture RESULTS_DIR/<--picture>, copied to docs/img/main_<name>.png. Nothing
outside the markers changes; every file is written atomically (a temporary file, then os.replace). A missing
file or field is one line on stderr and exit status 2. Standard library only (no navgym import): it runs
without the project installed.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
PICTURE = "paired_urban.png"
MIN_CI_EPISODES = 10  # envs.metrics.MIN_CI_EPISODES (a test keeps them equal): no CI below this many episodes
ALGOS = ("ppo", "sac", "td3", "recurrentppo")


class Failure(Exception):
    """One line for the user."""


def _field(d, *keys):
    """d[k0][k1]...; a missing key is a Failure naming its path."""
    path = "results.json"
    for k in keys:
        path += f"[{k!r}]"
        if not isinstance(d, dict) or k not in d:
            raise Failure(f"{path} is missing (not an eval.py results.json?)")
        d = d[k]
    return d


def short_label(label: str) -> str:
    """A row label: the short forms of eval.py's tables, per-scenario file paths dropped (``tuned b``, ``ppo``,
    ``rule``, ``oracle: ...``; a filter spec stays as it is)."""
    if label.startswith("oracle"):
        return label
    kind, sep, _ = label.partition(":")
    if sep and kind == "tuned":
        return "tuned b"
    if sep and kind.lower() in ALGOS:
        return kind.lower()
    if sep and kind == "rule":
        return "rule"
    return label


def _num(x, signed=False, digits=None) -> str:
    """``x`` with 2 decimals (3 below 0.1, unless ``digits`` says); 'n/a' for a missing or non-finite figure."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if digits is None:
        digits = 3 if 0 < abs(x) < 0.1 else 2
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def _pair_cell(r: dict) -> str:
    """The paired RMSE difference to the reference with its 95% CI ('(no CI)' below MIN_CI_EPISODES)."""
    p = r.get("paired_vs_reference")
    if p is None:
        return "n/a"
    d = p.get("diff_rmse_h_m")
    if p.get("episodes", 0) < MIN_CI_EPISODES:
        return f"{_num(d, True)} (no CI)"
    lo, hi = (p.get("diff_rmse_h_ci95_m") or [None, None])[:2]
    finite = [abs(v) for v in (d, lo, hi) if isinstance(v, (int, float)) and math.isfinite(v)]
    digits = 3 if finite and 0 < max(finite) < 0.1 else 2
    return f"{_num(d, True, digits)} [{_num(lo, True, digits)}, {_num(hi, True, digits)}]"


def _tuned_values(results: dict, scenarios: list) -> list:
    """``'scenario b'`` of each scenario's tuned method whose tuning.json can be read (paths as eval.py was given
    them: relative to the repository root)."""
    out = []
    for s in scenarios:
        for label in results["scenarios"][s]:
            kind, sep, path = label.partition(":")
            if not (sep and kind == "tuned"):
                continue
            f = Path(path.replace("{scenario}", s))
            try:
                t = json.loads((f if f.is_absolute() else ROOT / f).read_text())
                out.append(f"{s} {t['param']} = {t['best']:.4g}")
            except (OSError, ValueError, KeyError, TypeError):
                pass
    return out


ALT = {"paired": "each method's paired horizontal RMSE difference to the reference with its 95% CI",
       "error_vs_time": "median horizontal error over time and the paired difference to the reference",
       "cdf": "CDF of the horizontal error", "trajectory": "episode 0: the track and the position errors",
       "actions": "the parameter the policy set over time"}


def _alt(picture_rel: str) -> str:
    """The picture's alt text: what it shows, on which scenario (from eval.py's plot name <kind>_<scenario>)."""
    stem = Path(picture_rel).stem.removeprefix("main_")
    for kind, text in ALT.items():
        if stem.startswith(kind + "_"):
            return f"{stem[len(kind) + 1:]}: {text}"
    return stem


def build_block(results: dict, command: str, picture_rel: str | None) -> str:
    """The Markdown between the markers (without them)."""
    scen = _field(results, "scenarios")
    scenarios = list(scen)
    if not scenarios:
        raise Failure("results.json['scenarios'] is empty")
    episodes = _field(results, "config", "episodes")
    seed = _field(results, "config", "seed")
    ref_labels = _field(results, "config", "reference_labels")
    rows: dict = {}  # short label -> {scenario: metrics}, in the order of first appearance
    for s in scenarios:
        for label, r in scen[s].items():
            _field(scen, s, label, "rmse_h_m")
            rows.setdefault(short_label(label), {})
            if s in rows[short_label(label)]:  # two labels with one short form: keep the full label
                rows.setdefault(label, {})[s] = (label, r)
            else:
                rows[short_label(label)][s] = (label, r)
    refs = {s: _field(ref_labels, s) for s in scenarios}
    ref_short = sorted({short_label(v) for v in refs.values()})
    head = "| method | " + " | ".join(f"{s}: RMSE h [m] | {s}: vs reference [m] (95% CI)" for s in scenarios) + " |"
    lines = [
        f"Generated by `{command}` ({episodes} held-out episodes per scenario, seed {seed}; "
        "`python scripts/readme_results.py` wrote this block). Horizontal RMSE, and the paired RMSE difference to "
        f"the reference `{', '.join(ref_short)}` on the same episodes with its bootstrap 95% CI (negative: lower "
        "error than the reference).",
        "",
        head,
        "|---|" + "---:|---|" * len(scenarios),
    ]
    for name, per in rows.items():
        cells = []
        for s in scenarios:
            if s not in per:
                cells += ["-", "-"]
                continue
            label, r = per[s]
            cells.append(_num(r["rmse_h_m"]))
            cells.append("reference" if label == refs[s] else _pair_cell(r))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    tuned = _tuned_values(results, scenarios)
    if tuned:
        lines += ["", "tuned b: the optimized fixed forgetting factor of each scenario (" + "; ".join(tuned) + ")."]
    if picture_rel:
        lines += ["", f"![{_alt(picture_rel)}]({picture_rel})"]
    return "\n".join(lines)


def replace_block(text: str, block: str) -> str:
    """``text`` with the lines between the markers replaced by ``block``; the markers stay."""
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        raise Failure(f"README.md needs one '{BEGIN}' line followed by one '{END}' line")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{block}\n{END}{tail}"


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``path`` through a temporary file beside it and os.replace; it keeps the mode of the file it replaces
    (a new file: 0o666 less the umask, as open() would make it)."""
    if path.exists():
        mode = path.stat().st_mode & 0o777
    else:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def run(results_dir: Path, readme: Path, picture: str | None, command: str) -> None:
    rj = results_dir / "results.json"
    if not rj.is_file():
        raise Failure(f"{rj} is missing: run `bash scripts/main.sh` first (or give eval.py's --out folder)")
    try:
        results = json.loads(rj.read_text())
    except (OSError, ValueError) as e:
        raise Failure(f"{rj} is not readable JSON ({e})") from None
    if not readme.is_file():
        raise Failure(f"{readme} is missing")
    pic_rel = pic_src = None
    if picture:
        pic_src = results_dir / picture
        if not pic_src.is_file():
            raise Failure(f"{pic_src} is missing (eval.py writes the plots unless --no-plots)")
        pic_rel = f"docs/img/main_{Path(picture).stem}.png"
    text = readme.read_text()
    new = replace_block(text, build_block(results, command, pic_rel))
    if pic_src is not None:
        dst = readme.parent / pic_rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        _write_atomic(dst, pic_src.read_bytes())
    _write_atomic(readme, new.encode())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results_dir", nargs="?", default="results/main", help="eval.py's --out (default results/main)")
    p.add_argument("--readme", default=str(ROOT / "README.md"), help="the README to update (default: this tree's)")
    p.add_argument("--picture", default=PICTURE, help=f"plot of RESULTS_DIR to show (default {PICTURE}; '' none)")
    p.add_argument("--command", default="bash scripts/main.sh", help="the command the caption names")
    a = p.parse_args(argv)
    try:
        run(Path(a.results_dir), Path(a.readme), a.picture or None, a.command)
    except Failure as e:
        print(f"readme_results.py: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
