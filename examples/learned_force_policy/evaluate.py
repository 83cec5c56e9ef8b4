"""Evaluates policies on the benchmark suite's walls and tasks through the
vector environment, with the ablations a researcher tries when a learned
policy loses contact: the safety supervisor behind it, and limits on its
action. Not the benchmark (which ranks contenders: ``drake-contact
benchmark``): a quick harness for asking why.

    python examples/learned_force_policy/evaluate.py POLICY.json [...] [--suite standard]
        [--supervisor] [--limit FIELD=LOW:HIGH ...] [--out evaluation.json]

``POLICY``: a NumpyPolicy file, or ``zero`` (the hybrid law alone). Each
policy runs every task of the suite on its walls (wall i with noise seed i
and joint 2's drive at 1.2, as the suite runs them) for the suite's
duration. ``--limit force_gain_scale=-1:0`` clips that action field to
[-1, 0] (here: the force gain never above the law's own). Reported per
policy: the runs that lost contact (and on which walls), and the true
force's RMSE over the suite's scoring window after the first contact,
median and worst over the runs that kept contact (10 ms samples).
"""
import argparse
import json
from pathlib import Path

import numpy as np

from drake_contact.app.benchmark import SUITES
from drake_contact.control.policy import NumpyPolicy, zero_policy
from drake_contact.control.policy_spaces import ACTION
from drake_contact.gym import ForceTrackingVectorEnv


def limited(policy, limits):
    """``policy`` with its action's fields clipped to ``limits`` ({field: (low, high)})."""
    if not limits:
        return policy
    low, high = np.full(ACTION.size, -1.0), np.full(ACTION.size, 1.0)
    for field, (lo, hi) in limits.items():
        low[getattr(ACTION, field)], high[getattr(ACTION, field)] = lo, hi
    return lambda observation: np.clip(policy(observation), low, high)


def evaluate(policy, suite, supervisor=False):
    """Every (task, wall) run of ``suite``: a list of dicts."""
    runs = []
    for task in suite.tasks:
        envs = ForceTrackingVectorEnv(num_envs=len(suite.walls), task=task,
                                      duration_s=suite.duration_s, walls=suite.walls,
                                      supervisor=supervisor)
        observations, info = envs.reset(seed=0)
        n = envs.num_envs
        errors = [[] for _ in range(n)]
        first_contact = np.full(n, np.nan)
        # The last change of f_d by more than 1 N (a step of the square
        # wave), and where a contact loss came relative to it.
        last_step = np.full(n, np.nan)
        last_fd = np.full(n, np.nan)
        loss = [None] * n
        while True:
            actions = np.array([policy(o) for o in observations])
            observations, _, terminated, _, info = envs.step(actions)
            for i in np.flatnonzero(info["stepped"]):
                t, f_d = info["time_s"][i], info["force_desired"][i]
                if abs(f_d - last_fd[i]) > 1.0:
                    last_step[i] = t
                last_fd[i] = f_d
                if info["in_contact"][i] and np.isnan(first_contact[i]):
                    first_contact[i] = t
                since = t - first_contact[i]
                if suite.window_s[0] <= since <= suite.window_s[1]:
                    errors[i].append(info["force_true"][i] - f_d)
                if terminated[i]:
                    loss[i] = {"time_s": float(t), "after_first_contact_s": float(since),
                               "after_step_of_fd_s": float(t - last_step[i]),
                               "force_desired_n": float(f_d)}
            if not info["active"].any():
                break
        lost = info.get("contact_lost", np.zeros(n, bool))
        diverged = info.get("diverged", np.array([""] * n, dtype=object))
        for i, (k, b) in enumerate(suite.walls):
            rmse = float(np.sqrt(np.mean(np.square(errors[i])))) if errors[i] else None
            runs.append({"task": task, "stiffness": k, "damping": b,
                         "contact_lost": bool(lost[i]), "diverged": str(diverged[i]),
                         "rmse_n": rmse, "ended": loss[i]})
    return runs


def summary(runs):
    kept = [r["rmse_n"] for r in runs if not r["contact_lost"] and not r["diverged"]
            and r["rmse_n"] is not None]
    lost = [r for r in runs if r["contact_lost"] or r["diverged"]]
    return {"runs": len(runs), "contact_lost": len(lost),
            "lost_on_walls": sorted({int(r["stiffness"]) for r in lost}),
            "median_rmse_n": float(np.median(kept)) if kept else None,
            "worst_rmse_n": float(np.max(kept)) if kept else None}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policies", nargs="+")
    parser.add_argument("--suite", default="standard", choices=sorted(SUITES))
    parser.add_argument("--supervisor", action="store_true")
    parser.add_argument("--limit", action="append", default=[])
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    limits = {}
    for item in args.limit:
        field, _, bounds = item.partition("=")
        if field not in ACTION.names():
            parser.error(f"--limit {item}: the field must be one of {', '.join(ACTION.names())}")
        try:
            lo, hi = (float(v) for v in bounds.split(":"))
        except ValueError:
            parser.error(f"--limit {item}: give FIELD=LOW:HIGH, each in [-1, 1]")
        if not -1.0 <= lo <= hi <= 1.0:
            parser.error(f"--limit {item}: LOW and HIGH must satisfy -1 <= LOW <= HIGH <= 1")
        limits[field] = (lo, hi)
    results = {}
    for name in args.policies:
        policy = zero_policy if name == "zero" else NumpyPolicy.load(name)
        runs = evaluate(limited(policy, limits), SUITES[args.suite], args.supervisor)
        results[name] = {"summary": summary(runs), "runs": runs}
        print(json.dumps({"policy": name, "supervisor": args.supervisor, "limits": limits}
                         | results[name]["summary"]), flush=True)
    if args.out:
        args.out.write_text(json.dumps({"suite": args.suite, "supervisor": args.supervisor,
                                        "limits": limits, "results": results}, indent=1))


if __name__ == "__main__":
    main()
