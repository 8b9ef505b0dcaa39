"""One entry point for training (DESIGN.md section 4).

    python train.py rl   --env GnssIns/SageHusa-v1 --algo ppo --timesteps N --seed S --out runs/DIR
    python train.py rl   --env GnssIns/SageHusa-v1 --algo ppo --quick --out runs/quick
    python train.py tune --env GnssIns/SageHusa-v1 --out runs/DIR          # the optimized fixed parameter
    python train.py zupt --model lstm --seed S --out runs/DIR              # zero-velocity detector
    python train.py learned-r --seed S --out runs/DIR [--quick]            # supervised per-satellite R
    python train.py sweep --config configs/sweep.yml --out runs/sweep [--backend ray [--address ADDR]]

``rl`` writes ``runs/DIR/model.zip`` (stable-baselines3), ``config.json`` (the exact settings),
``vecnormalize.pkl`` (when observations are normalized), ``best/best_model.zip`` (best held-out
evaluation; with its ``best/vecnormalize.pkl``), ``checkpoints/`` and ``logs/`` (CSV + tensorboard), and
``INCOMPLETE`` while the training has not finished (after a Ctrl-C it says at which step it stopped and what was
kept; Ctrl-C ends any subcommand with one line and exit status 130); eval.py takes
any of the three models (``ppo:runs/DIR/best/best_model.zip``) with the statistics saved with it. ``tune`` writes ``runs/DIR/tuning.json``
for ``eval.py --methods tuned:runs/DIR/tuning.json``. ``zupt`` writes the detector's weights and
``metrics.json``. ``learned-r`` writes ``model.pt``, ``config.json`` and ``metrics.json`` of the per-satellite
noise model (:mod:`agents.learned_r`) for ``eval.py --methods learned-r:runs/DIR/model.pt``.
``sweep`` runs a grid / random or Optuna search of ``rl`` runs (:mod:`agents.sweep`; on Ray Tune with
``--backend ray``) and writes ``sweep.csv`` / ``sweep.md`` beside the trials' run folders.

The environments also train unchanged under RL Zoo, with navgym's hyperparameters from ``hyperparams/``:
``python -m rl_zoo3.train --gym-packages envs --env GnssIns/SageHusa-v1 --algo ppo --conf-file hyperparams/ppo.yml``.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path


def fail(msg: str):
    print(f"train.py: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def parse_env_kwargs(items) -> dict:
    """``key=value`` strings -> dict; values parsed as YAML scalars (numbers, booleans, strings), and an exponent
    number YAML 1.1 leaves a string (``1e-9``, ``5e3``) as a float."""
    import re
    import yaml
    out = {}
    for item in items or []:
        if "=" not in item:
            fail(f"--env-kwargs expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        try:
            val = yaml.safe_load(v)
        except yaml.YAMLError:
            fail(f"--env-kwargs: cannot parse the value of {k!r}: {v!r}")
        if isinstance(val, str) and re.fullmatch(r"[+-]?(\d+\.?\d*|\.\d+)[eE][+-]?\d+", val.strip()):
            val = float(val)
        out[k.strip()] = val
    return out


def check_env_kwargs(env_id: str, kwargs: dict):
    """Validate env kwargs by building the env's config (one-line error, exit 2)."""
    from agents.rollout import env_class
    from envs.core import check_method_has_params
    cls = env_class(env_id)
    try:
        cfg = cls.config_from(kwargs)
        if cls.PARAMS:  # an env of an adaptive law's knob: the method must run that law
            check_method_has_params(cfg.method, cls.PARAMS, cls.DEFAULTS["method"])
    except ValueError as e:
        fail(str(e))


def build_parser():
    from agents.training import DEFAULT_SETTINGS as D, QUICK as Q
    from cli_help import HelpFormatter
    p = argparse.ArgumentParser(prog="train.py", description="Train tuning policies, the optimized fixed "
                                "parameter, and zero-velocity detectors.", formatter_class=HelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    rl = sub.add_parser("rl", help="train an RL tuning policy (stable-baselines3)", formatter_class=HelpFormatter)
    rl.add_argument("--env", default="GnssIns/SageHusa-v1", help="environment id")
    rl.add_argument("--algo", default="ppo", help="ppo, sac, td3 or recurrentppo")
    rl.add_argument("--timesteps", type=float, default=None,
                    help=f"total environment steps (default: {D['n_timesteps']}; --quick: {Q['n_timesteps']}; or the "
                         "--config file's)")
    rl.add_argument("--seed", type=int, default=0, help="training seed (worlds, policy initialization)")
    rl.add_argument("--n-envs", type=int, default=None,
                    help=f"rows of the native vector env (default: {D['n_envs']}; --quick: {Q['n_envs']}; or the "
                         "--config file's)")
    rl.add_argument("--env-kwargs", nargs="*", metavar="KEY=VALUE",
                    help="environment arguments, e.g. scenario=urban episode_length_s=300 (default: the env's; "
                         f"--quick: episode_length_s={Q['env_kwargs']['episode_length_s']:g})")
    rl.add_argument("--config", default=None,
                    help="RL Zoo style YAML hyperparameter file, e.g. hyperparams/ppo.yml (default: none, "
                         "navgym's own hyperparameters)")
    rl.add_argument("--quick", action="store_true",
                    help=f"a small run: {Q['n_timesteps']} steps, {Q['n_envs']} envs, "
                         f"{Q['env_kwargs']['episode_length_s']:g} s episodes (measured on 2 busy cores: PPO about 1 "
                         "minute, recurrentppo about 1.5 minutes)")
    rl.add_argument("--no-normalize", action="store_true", help="no VecNormalize (default: normalize)")
    rl.add_argument("--no-progress", action="store_true", help="no progress bar (default: show one)")
    rl.add_argument("--out", required=True, help="output directory runs/DIR (required)")
    tu = sub.add_parser("tune", help="the optimized fixed-parameter baseline (grid search on training seeds)",
                        formatter_class=HelpFormatter)
    tu.add_argument("--env", default="GnssIns/SageHusa-v1", help="environment id whose parameter is tuned")
    tu.add_argument("--env-kwargs", nargs="*", metavar="KEY=VALUE",
                    help="environment arguments of the training episodes, e.g. scenario=urban "
                         "episode_length_s=300 (default: the env's)")
    tu.add_argument("--param", default=None, help="parameter to tune (default: the env's first)")
    tu.add_argument("--n-train", type=int, default=16, help="training episodes per grid value")
    tu.add_argument("--grid-size", type=int, default=13, help="grid values over the parameter's range")
    tu.add_argument("--seed", type=int, default=0, help="seed of the training episodes")
    tu.add_argument("--out", required=True, help="output directory; writes OUT/tuning.json (required)")
    zu = sub.add_parser("zupt", help="train a zero-velocity detector", formatter_class=HelpFormatter)
    zu.add_argument("--model", required=True, choices=("mlp", "lstm"), help="detector model (required)")
    zu.add_argument("--seed", type=int, default=0, help="training seed")
    zu.add_argument("--quick", action="store_true", help="a small, fast run (smaller data set and fewer epochs)")
    zu.add_argument("--out", required=True, help="output directory: weights, metrics.json (required)")
    lr = sub.add_parser("learned-r", help="train the supervised per-satellite noise model (the learned-r baseline)",
                        formatter_class=HelpFormatter)
    lr.add_argument("--seed", type=int, default=0, help="training seed (worlds, exploration, initialization), 0..79")
    lr.add_argument("--quick", action="store_true", help="a small, fast run (fewer and shorter episodes, fewer epochs)")
    lr.add_argument("--scenarios", default=None, metavar="A,B",
                    help="simulated scenarios the training episodes are drawn from, comma-separated (default "
                         "urban,urban-transition; urban-smartloc is calibrated to the smartLoc recording)")
    lr.add_argument("--no-progress", action="store_true", help="no progress lines (default: show them)")
    lr.add_argument("--out", required=True, help="output directory: model.pt, config.json, metrics.json (required)")
    sw = sub.add_parser("sweep", help="a grid / random or Optuna search of rl runs (Ray Tune with --backend ray)",
                        formatter_class=HelpFormatter)
    sw.add_argument("--config", required=True,
                    help="sweep file (YAML; see configs/sweep.yml, configs/sweep_optuna.yml)")
    sw.add_argument("--out", required=True, help="sweep folder: the trials' run folders, sweep.csv, sweep.md")
    sw.add_argument("--backend", default="local", choices=("local", "ray"),
                    help="local: the trials one after another here (default); ray: Ray Tune trials on a local "
                         "Ray or a cluster (--address)")
    sw.add_argument("--address", default=None, metavar="ADDR", help="--backend ray: join this Ray cluster")
    sw.add_argument("--workers", type=int, default=None, metavar="N",
                    help="--backend ray: trials at once (a local Ray gets N CPUs; default: all cores)")
    return p


def check_common(args) -> None:
    """Numbers every subcommand takes, checked before any work: one line, exit 2."""
    if args.seed < 0:
        fail(f"--seed must be >= 0, got {args.seed}")
    if Path(args.out).is_file():
        fail(f"--out {args.out!r} is a file, not a directory")
    if getattr(args, "timesteps", None) is not None:
        from agents.training import MAX_TIMESTEPS
        if not (math.isfinite(args.timesteps) and args.timesteps >= 1):
            fail(f"--timesteps must be a finite number >= 1, got {args.timesteps!r}")
        if args.timesteps > MAX_TIMESTEPS or args.timesteps != int(args.timesteps):
            fail(f"--timesteps must be a whole number of steps <= {MAX_TIMESTEPS:.0e} (about 23 days at 5000 "
                 f"env-steps/s), got {args.timesteps:g}")
    if getattr(args, "n_envs", None) is not None and args.n_envs < 1:
        fail(f"--n-envs must be >= 1, got {args.n_envs}")
    for name in ("n_train", "grid_size"):
        v = getattr(args, name, None)
        if v is not None and v < (2 if name == "grid_size" else 1):
            fail(f"--{name.replace('_', '-')} must be >= {2 if name == 'grid_size' else 1}, got {v}")


_MADE: list = []
"""Output folders this run created (removed again when the run ends by an error or Ctrl-C and left them empty)."""


def announce() -> None:
    """One line when navgym's numba kernels compile in this run (a first run: minutes; :mod:`earth.numba_cache`)."""
    from earth.numba_cache import announce_compilation
    announce_compilation()


def check_out(out) -> None:
    """Create the output folder, or exit with one line when it cannot be written (before any work)."""
    from envs.outputs import check_output_dir
    existed = Path(out).exists()
    try:
        check_output_dir(out)
    except ValueError as e:
        fail(str(e))
    if not existed:
        _MADE.append(Path(out))


def main(argv=None):
    """The command line (module docstring). Ctrl-C ends it with one line and exit status 130: ``rl`` marks its
    run folder incomplete (:data:`agents.training.INCOMPLETE`; ``best/`` and ``checkpoints/`` are kept); an
    output folder this run created and left empty is removed, after an error too."""
    from envs.outputs import remove_if_empty
    _MADE.clear()
    try:
        return _main(argv)
    except KeyboardInterrupt as e:
        for d in _MADE:
            remove_if_empty(d)
        print(f"train.py: interrupted{': ' + str(e) if str(e) else ' (Ctrl-C)'}", file=sys.stderr)
        raise SystemExit(130) from None
    except BaseException:
        for d in _MADE:
            remove_if_empty(d)
        raise


def _main(argv=None):
    args = build_parser().parse_args(argv)
    if args.cmd == "sweep":
        rows = sweep_cli(args)
        if any(r.status == "error" for r in rows):
            raise SystemExit(1)  # after the tables: a script does not go on with missing runs
        return rows
    check_common(args)
    if args.cmd == "rl":
        from agents.policies import ALGOS
        if args.algo.lower() not in ALGOS:
            fail(f"unknown algorithm {args.algo!r}; known: {', '.join(ALGOS)}")
        import envs
        if not envs.is_env_id(args.env):
            fail(f"unknown environment {args.env!r}; known: {', '.join(sorted(envs.ENV_IDS))}")
        ekw = parse_env_kwargs(args.env_kwargs)
        check_env_kwargs(args.env, ekw)
        from agents.training import train_rl
        check_out(args.out)
        announce()
        try:
            cfg = train_rl(args.env, args.algo, args.out, timesteps=args.timesteps, seed=args.seed,
                           n_envs=args.n_envs, env_kwargs=ekw, config_file=args.config, quick=args.quick,
                           normalize=False if args.no_normalize else None, progress=not args.no_progress)
        except (ValueError, FileNotFoundError) as e:
            fail(str(e))
        print(f"trained {cfg['algo']} on {cfg['env']} for {cfg['n_timesteps']} steps in {cfg['wall_time_s']:.0f} s "
              f"({cfg['env_steps_per_s']:.0f} env-steps/s); model: {Path(args.out) / 'model.zip'}")
    elif args.cmd == "tune":
        import envs
        if not envs.is_env_id(args.env):
            fail(f"unknown environment {args.env!r}; known: {', '.join(sorted(envs.ENV_IDS))}")
        ekw = parse_env_kwargs(args.env_kwargs)
        check_env_kwargs(args.env, ekw)
        from agents.rollout import env_class
        from agents.tuning import default_grid, save_tuning, tune_fixed_parameter
        specs = {s.name: s for s in env_class(args.env).PARAMS}
        if not specs:
            fail(f"{args.env} acts per receiver channel: it has no scalar parameter to tune")
        param = args.param or next(iter(specs))
        if param not in specs:
            fail(f"{args.env} has no parameter {param!r}; known: {', '.join(specs)}")
        check_out(args.out)
        announce()
        try:
            res = tune_fixed_parameter(args.env, ekw, param, default_grid(specs[param], args.grid_size),
                                       n_train=args.n_train, seed=args.seed, progress=True)
        except (ValueError, FileNotFoundError) as e:
            fail(str(e))
        path = save_tuning(res, Path(args.out) / "tuning.json")
        print(f"wrote {path}")
    elif args.cmd == "learned-r":
        from agents.learned_r import MAX_RUN_SEED, QUICK, LearnedRConfig, train_learned_r
        if args.seed > MAX_RUN_SEED:
            fail(f"--seed must be in 0..{MAX_RUN_SEED} (the training seeds stay below the validation seeds), "
                 f"got {args.seed}")
        import dataclasses
        cfg = dataclasses.replace(QUICK if args.quick else LearnedRConfig(), seed=args.seed)
        if args.scenarios is not None:
            try:
                cfg = dataclasses.replace(cfg, scenarios=tuple(x.strip() for x in args.scenarios.split(",")))
            except ValueError as e:
                fail(f"--scenarios: {e}")
        check_out(args.out)
        announce()
        m = train_learned_r(args.out, cfg, quick=args.quick, progress=not args.no_progress)
        t, auc = m["test"], m["test"]["auc_nlos"]
        print(f"learned-r: held-out NLL {t['nll_m']:.3f} (reported sigmas {t['nll_reported_m']:.3f}, true variances "
              f"{t['nll_true_var_m']:.3f}), NLOS AUC {'n/a' if auc is None else f'{auc:.3f}'}, best epoch "
              f"{m['training']['best_epoch']} of {m['training']['epochs']}")
        print(f"wrote {', '.join(str(p) for p in sorted(Path(args.out).iterdir()) if p.is_file())}")
    else:
        try:
            from agents.zupt_training import format_table, train_zupt_detector
        except ImportError as e:
            fail(f"zero-velocity detector training is not available: {e}")
        check_out(args.out)
        announce()
        metrics = train_zupt_detector(args.model, args.seed, Path(args.out), quick=args.quick, progress=True)
        print(format_table(metrics))  # the full metrics (per drive, thresholds, history) are in metrics.json
        print(f"wrote {', '.join(str(p) for p in sorted(Path(args.out).iterdir()) if p.is_file())}")


def sweep_cli(args):
    """``train.py sweep``: arguments and the sweep file checked before any work (one line, exit 2); the
    trials run and the tables are written; returns the table's rows (``main`` exits 1 if a trial failed)."""
    from agents.backends import BackendUnavailable, check_backend_args, make_backend
    from agents.sweep import expand_trials, load_sweep, run_sweep
    try:
        check_backend_args(args.backend, args.address, args.workers)
        cfg = load_sweep(args.config)
        expand_trials(cfg, args.out)
    except (ValueError, FileNotFoundError, BackendUnavailable) as e:
        fail(str(e))
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        fail(f"--out {str(out)!r} is a file, not a directory")
    try:
        backend = make_backend(args.backend, args.address, args.workers)
    except BackendUnavailable as e:
        fail(str(e))
    announce()
    with backend:
        rows = run_sweep(cfg, out, backend)
    print((out / "sweep.md").read_text())
    n_err = sum(r.status == "error" for r in rows)
    print(f"wrote {out / 'sweep.csv'}, {out / 'sweep.md'}, {out / 'sweep.json'}"
          + (f"; {n_err} of {len(rows)} trials failed (see the table)" if n_err else ""))
    return rows


if __name__ == "__main__":
    main()
