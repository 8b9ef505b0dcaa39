"""``python -m envs.datasets check SPEC``: load a recorded data set and summarize it (issue 12).

Prints the observation span, epochs, satellites used per system, the truth's
coverage of the epochs, Doppler availability, and the single-point solution's
horizontal error against the truth (p50 / p95), the IMU, the pseudorange
sigma model (its C/N0 checked where it needs one) and the recorded odometry
of an ``[odometry]`` section. Exit status 0 when the set
loads and at least one epoch has both a valid SPP and truth; 1 with a one-line
``check: error: ...`` otherwise (a bad spec key, a missing file, a damaged
file, no overlap with the truth, no usable epoch).
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from earth import C_en, ecef_to_geodetic

from .epochs import GnssEpochs
from .spline_truth import fit_positions
from .spp import solve_spp

__all__ = ["DatasetCheck", "check_dataset", "format_check", "main"]


@dataclass(frozen=True)
class DatasetCheck:
    """What :func:`check_dataset` measured (see :func:`format_check`)."""

    name: str
    source: str
    n_epochs: int
    span_s: float
    t0_gps: float | None
    satellites: dict
    truth_rows: int
    truth_covered: int
    n_prr: int
    spp_epochs: int
    spp_h_p50_m: float
    spp_h_p95_m: float
    imu: str = ""
    sigma_model: str = ""
    odometry: str = ""


def _epochs_and_truth(spec):
    """(GnssEpochs, truth times on the epochs' time base, truth ECEF, smartLoc odometry or None) of a spec."""
    if spec.gnss.format == "smartloc":
        from .epochs import SYSTEM_LETTERS
        from .smartloc import load_smartloc
        g = spec.gnss
        data = load_smartloc(g.obs.parent, g.obs.name[:-len("_Input.txt")])
        ep = data.epochs(systems=tuple(SYSTEM_LETTERS[s] for s in g.systems), min_elevation_deg=g.elevation_mask_deg,
                         min_cn0_dbhz=g.min_cn0_dbhz)
        return ep, data.ground_truth.t, data.ground_truth.r_e, data.odometry
    from .dataset_world import prepare_rinex
    rec = prepare_rinex(spec)
    return rec.epochs, rec.truth.t - rec.epochs.t0_gps, rec.truth.r_e, None


def check_dataset(spec) -> DatasetCheck:
    """Load ``spec`` (a :class:`~envs.datasets.spec.DatasetSpec`) and measure it (module docstring)."""
    ep, t_tr, r_tr, odometry = _epochs_and_truth(spec)
    if not isinstance(ep, GnssEpochs):  # pragma: no cover - loaders return GnssEpochs
        raise TypeError("loader did not return GnssEpochs")
    model = spec.gnss.sigma_model
    ep = ep.with_sigma_model(model, spec.gnss.obs)        # the SPP weights as the filter; a missing C/N0 raises
    inside = (ep.t >= t_tr[0]) & (ep.t <= t_tr[-1])
    sats = {}
    from .epochs import SYSTEM_NAMES
    for code in np.unique(ep.system[ep.mask]):
        sats[SYSTEM_NAMES[int(code)]] = int(np.unique(ep.sat_id[ep.mask & (ep.system == code)]).size)
    sol = solve_spp(ep.sat_pos, ep.pr, ep.mask, ep.pr_sigma, ep.system)
    use = sol.valid & inside
    p50 = p95 = math.nan
    if use.any():
        fit = fit_positions(t_tr, r_tr)
        r_true = fit.position(ep.t[use])
        lat, lon, _ = ecef_to_geodetic(r_true)
        d = (np.swapaxes(C_en(lat, lon), -1, -2) @ (sol.r_e[use] - r_true)[..., None])[..., 0]
        h = np.hypot(d[:, 0], d[:, 1])
        p50, p95 = float(np.percentile(h, 50)), float(np.percentile(h, 95))
    return DatasetCheck(name=spec.name, source=ep.source, n_epochs=ep.n_epochs, span_s=float(ep.t[-1] - ep.t[0]),
                        t0_gps=ep.t0_gps, satellites=sats, truth_rows=int(np.size(t_tr)),
                        truth_covered=int(inside.sum()), n_prr=0 if ep.prr is None else
                        int((ep.mask & (ep.prr_sigma < 1e3)).sum()), spp_epochs=int(use.sum()),
                        spp_h_p50_m=p50, spp_h_p95_m=p95, imu=_imu_summary(spec, ep),
                        sigma_model=model.name, odometry=_odometry_summary(spec, odometry, ep))


def _odometry_summary(spec, odometry, ep) -> str:
    """One line on the recorded odometry of an ``[odometry]`` section ('' without one)."""
    o = spec.odometry
    if o is None:
        return ""
    t = odometry.t
    covered = int(((ep.t >= t[0]) & (ep.t <= t[-1])).sum())
    fused = "speed + NHC" + (f" + yaw rate (sigma {o.yaw_rate_sigma_dps:g} deg/s)" if o.yaw_rate else "")
    return (f"recorded odom3: {t.size} rows over {t[-1] - t[0]:.1f} s, covers {covered} of {ep.n_epochs} epochs; "
            f"fused: {fused}, speed sigma {o.speed_sigma_mps:g} m/s, NHC {o.nhc_sigma_mps:g} m/s")


def _imu_summary(spec, ep) -> str:
    """One line on the IMU: the synthesized grade and rate, or the recorded file read and checked."""
    imu = spec.imu
    if imu.source == "synthesized":
        return f"synthesized from the truth, {imu.grade} grade at {imu.rate_hz:g} Hz"
    from .dataset_world import prepare_rinex
    from .recorded_imu import read_imu_csv
    t, _, _ = read_imu_csv(imu, prepare_rinex(spec).week_ref)
    t = t - ep.t0_gps
    dt = np.diff(t)
    covered = int(((ep.t >= t[0]) & (ep.t <= t[-1])).sum())
    return (f"recorded {imu.file.name}: {t.size} rows over {t[-1] - t[0]:.1f} s, step median "
            f"{1e3 * float(np.median(dt)):.1f} ms, largest {1e3 * float(dt.max()):.0f} ms; covers {covered} of "
            f"{ep.n_epochs} epochs; {imu.grade} grade for the filter, replayed at {imu.rate_hz:g} Hz")


def format_check(c: DatasetCheck) -> str:
    """The printed summary of :func:`check_dataset`."""
    t0 = "" if c.t0_gps is None else f", GPS time of week {c.t0_gps:.1f}-{c.t0_gps + c.span_s:.1f} s"
    sats = ", ".join(f"{k} {v}" for k, v in c.satellites.items()) or "none"
    lines = [f"{c.name}: {c.source}",
             f"  epochs: {c.n_epochs} over {c.span_s:.1f} s{t0}",
             f"  satellites used: {sats}",
             f"  truth: {c.truth_rows} rows, covers {c.truth_covered} of {c.n_epochs} epochs",
             f"  pseudorange rates (Doppler): {c.n_prr}" if c.n_prr else "  pseudorange rates (Doppler): none",
             f"  SPP vs truth over {c.spp_epochs} epochs: horizontal p50 {c.spp_h_p50_m:.2f} m, "
             f"p95 {c.spp_h_p95_m:.2f} m"] + ([f"  IMU: {c.imu}"] if c.imu else [])
    if c.sigma_model and c.sigma_model != "receiver":
        lines.append(f"  pseudorange sigma: {c.sigma_model} model")
    if c.odometry:
        lines.append(f"  odometry: {c.odometry}")
    return "\n".join(lines)


def build_parser():
    """The parser of ``python -m envs.datasets`` (its help names the shipped specs)."""
    import argparse
    from .spec import SPEC_DIR
    shipped = "".join(f"\n  {f.stem}" for f in sorted(SPEC_DIR.glob("*.toml")))
    p = argparse.ArgumentParser(
        prog="python -m envs.datasets", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Recorded data sets, replayed as scenarios of eval.py and the environments. A dataset spec\n"
                    "is a small TOML file naming the observation, navigation and truth files.",
        epilog="shipped specs (give the name or a path to your own *.toml):" + shipped)
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("check", help="load a dataset spec (path or shipped name), check its data for physical "
                                     "plausibility and print its summary")
    c.add_argument("spec", nargs="+", help="dataset spec file (*.toml) or shipped name")
    return p


def main(argv=None) -> int:
    """Command line: ``python -m envs.datasets check SPEC_OR_NAME [...]``; returns the exit status."""
    p = build_parser()
    args = p.parse_args(argv)
    from .spec import dataset_spec_of
    status = 0
    for s in args.spec:
        try:
            spec = dataset_spec_of(s)
            if spec is None:
                raise ValueError(f"{s!r} is neither a dataset spec path (*.toml) nor a shipped data set name")
            res = check_dataset(spec)
            if res.spp_epochs == 0:
                raise ValueError(f"{spec.path}: no epoch has both a single-point solution and truth")
        except (ValueError, FileNotFoundError, ImportError) as exc:
            print(f"check: error: {exc}", file=sys.stderr)
            status = 1
            continue
        print(format_check(res))
    return status
