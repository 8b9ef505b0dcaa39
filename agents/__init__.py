"""Agents: RL training glue (stable-baselines3), baseline policies, the optimized fixed-parameter
baseline, and evaluation of policies on paired episodes.

* :mod:`agents.policies` -- constant-action and learned (SB3 ``model.zip``) policies behind one ``act`` interface;
* :mod:`agents.rollout` -- run a policy on B paired episodes through the batched env core;
* :mod:`agents.tuning` -- the optimized fixed-parameter baseline (grid search on training seeds);
* :mod:`agents.oracles` -- hindsight oracles of an env's knob (greedy schedule, best constant per episode,
  cross-fitted schedule): the headroom of a policy in that action space;
* :mod:`agents.methods` -- method specifications of eval.py (filters, fixed parameters, tuned, learned);
* :mod:`agents.training` -- ``train.py rl``;
* :mod:`agents.set_policy` -- permutation-equivariant SB3 policies for the per-satellite envs (PPO, RecurrentPPO, SAC);
* :mod:`agents.backends` -- where independent work runs: this process or Ray (tasks and Ray Tune trials);
* :mod:`agents.eval_batches` -- eval.py's paired episode batches as units of work for a backend.
"""
