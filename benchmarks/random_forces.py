"""The random-force ECFM against a standard fit of the same problem (issue 37 item 5).

Three steady problems with constraint forces, each on ``--n-datasets`` seeded noisy data
sets:

* ``rod-4``: the reaction rod of ``ecfm-uq reproduce coverage``'s ``operator`` block (its
  rate inside the operator, 4 sensors, 2 % noise, consistent data: tau-hat is mostly 0);
* ``rod-6-source``: the 6-sensor rod of its ``discrepancy`` block with the narrow source
  it does not have (amplitude 16: tau-hat > 0, the search's flat valley);
* ``beam``: the stochastic beam of Section 3.3 (``P > 1`` chaos coefficients), its mean
  readings with 2 % noise, the load bounded below buckling.

Every data set is fitted by ``fit(..., formulation="standard")`` and by
``fit(..., formulation="ecfm-random")`` (and with ``--sparse`` by the sparse prior too), the
two taking turns in this one process (the machine is shared: alternating keeps a change of
load from favouring either side); the times are summed over the data sets. One BLAS
thread, as ``ecfm-uq reproduce`` runs. With
``--profiles`` the profile-likelihood intervals of both fits are timed as well. The
random-force fit minimizes its profiled marginal likelihood with its exact gradient
(:mod:`ecfm_uq.inverse.formulations.random_force_gradient`), by Fisher scoring where
tau-hat > 0 at the standard estimate
(:mod:`ecfm_uq.inverse.formulations.random_force_scoring`).

Last lines: ``random_forces <problem> ecfm-random/standard fit time ratio: <float>`` (all
measured in this run). The per-form lines also give the random-force fits' model solves
per data set (``result.extra["n_solves"]``: the shared prior's search and the sparse
prior's, not the standard fit inside), a count the machine's load does not change.

With ``--stages`` the random-force fits' model solves are attributed to where they
happen: the eps search (``search``), the uncertainty (``uncertainty``: the delta method's
Hessian, by central differences of the exact gradient at the estimate, where it is the
observed information; none after Fisher scoring: the expected information), the restricted
test of tau = 0 (``test``) and the rest of the fit (``other``: the estimate's own
evaluation, the intervals' likelihood); the machine's load averages are printed first and
last (the times are shared with whatever else runs).

Run: ``python benchmarks/random_forces.py [--n-datasets 20] [--sparse] [--profiles]
[--stages]``.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import os
import time

import numpy as np
from threadpoolctl import threadpool_limits

from ecfm_uq.inverse import SteadyProblem, fit, profile_likelihood
from ecfm_uq.inverse.formulations import random_force_search, random_forces
from ecfm_uq.problems.beam import BeamModel
from ecfm_uq.problems.reaction import ReactionRod
from ecfm_uq.system import solve_steady


def problems():
    """name -> (problem with clean data, clean readings, truth, sigma, fit keywords, source)"""
    out = {}
    rod = ReactionRod(4)
    truth = np.array([0.5, 20.0])
    clean = rod.data(truth)
    out["rod-4"] = (rod.system, rod.M_obs, clean, truth, 0.02, {}, clean)
    rod6 = ReactionRod(6)
    truth6 = np.array([1.5, 20.0])
    clean6 = rod6.data(truth6)
    out["rod-6-source"] = (rod6.system, rod6.M_obs, clean6, truth6, 0.02, {},
                           rod6.data(truth6, 16.0, 0.62))  # fmt: skip
    beam = BeamModel(n_basis=6, order=5, sensors=[0.2, 0.4, 0.6, 0.8, 1.0])
    tb = np.array([1.0])
    cb = np.asarray(beam.M_obs @ beam.system.mean(solve_steady(beam.system, tb).Theta))
    bounds = {"bounds": [(0.0, 0.99 * beam.beta_min)]}
    out["beam"] = (beam.system, beam.M_obs, cb, tb, 0.02, bounds, cb)
    return out


@contextlib.contextmanager
def stage_counter():
    """Counts the random-force model's solves (``RandomForceModel.linearize``) by stage
    while active: yields the counter (stage -> solves)."""
    counts = collections.Counter()
    current = ["other"]
    model = random_forces.RandomForceModel
    saved = {
        "linearize": model.linearize,
        "restricted_test": model.restricted_test,
        "run": random_force_search.Search.run,
        "run_sparse": random_force_search.Search.run_sparse,
        "_uncertainty": random_forces._uncertainty,
    }

    def staged(name, f):
        def wrapper(*args, **kwargs):
            outer, current[0] = current[0], name
            try:
                return f(*args, **kwargs)
            finally:
                current[0] = outer

        return wrapper

    def linearize(self, *args, **kwargs):
        counts[current[0]] += 1
        return saved["linearize"](self, *args, **kwargs)

    model.linearize = linearize
    model.restricted_test = staged("test", saved["restricted_test"])
    random_force_search.Search.run = staged("search", saved["run"])
    random_force_search.Search.run_sparse = staged("search", saved["run_sparse"])
    random_forces._uncertainty = staged("uncertainty", saved["_uncertainty"])
    try:
        yield counts
    finally:
        model.linearize, model.restricted_test = saved["linearize"], saved["restricted_test"]
        random_force_search.Search.run = saved["run"]
        random_force_search.Search.run_sparse = saved["run_sparse"]
        random_forces._uncertainty = saved["_uncertainty"]


def main(argv=None):
    # one BLAS thread, as `ecfm-uq reproduce` runs (threaded BLAS on these small dense
    # solves only oversubscribes the cores: a 16 x 16 back-substitution took 8 ms)
    with threadpool_limits(limits=1, user_api="blas"):
        _main(argv)


def _main(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-datasets", type=int, default=20)
    parser.add_argument("--sparse", action="store_true", help="time the sparse prior too")
    parser.add_argument("--profiles", action="store_true", help="time the profiles too")
    parser.add_argument(
        "--stages", action="store_true", help="count the random-force fits' solves by stage"
    )
    args = parser.parse_args(argv)
    print(f"load averages at the start: {os.getloadavg()}")
    forms = [("standard", None), ("ecfm-random", None)]
    if args.sparse:
        forms.append(("ecfm-random sparse", {"force_prior": "sparse"}))
    ratios = []
    for name, (system, M, clean, truth, rel, kw, source) in problems().items():
        sigma = rel * float(np.abs(clean).mean())
        problem = SteadyProblem(system, M, clean)
        rng = np.random.default_rng(0)
        times = {f: 0.0 for f, _ in forms}
        ptimes = {f: 0.0 for f, _ in forms}
        statuses = {f: {} for f, _ in forms}
        solves = {f: 0 for f, _ in forms}
        stages = {f: collections.Counter() for f, _ in forms}
        for _ in range(args.n_datasets):
            v = source + sigma * rng.standard_normal(source.size)
            for form, options in forms:
                t = time.perf_counter()
                res = fit(problem.with_data(v), truth, formulation=form.split()[0],
                          sigma=sigma, options=options, **kw)  # fmt: skip
                times[form] += time.perf_counter() - t
                if args.stages and form != "standard":
                    with stage_counter() as counts:  # again, counted (not timed)
                        fit(problem.with_data(v), truth, formulation=form.split()[0],
                            sigma=sigma, options=options, **kw)  # fmt: skip
                    stages[form].update(counts)
                statuses[form][res.status.name] = statuses[form].get(res.status.name, 0) + 1
                solves[form] += res.extra.get("n_solves", 0)
                if args.profiles:
                    t = time.perf_counter()
                    profile_likelihood(res)
                    ptimes[form] += time.perf_counter() - t
        R = args.n_datasets
        for form, _ in forms:
            extra = f", profiles {ptimes[form] / R * 1e3:8.1f} ms" if args.profiles else ""
            if form != "standard":
                extra += f", {solves[form] / R:6.1f} model solves"
            print(f"{name:14s} {form:20s} fit {times[form] / R * 1e3:8.1f} ms per data set"
                  f"{extra}  statuses {statuses[form]}")  # fmt: skip
            if args.stages and form != "standard":
                per = {k: round(c / R, 2) for k, c in sorted(stages[form].items())}
                print(f"{'':14s} {form:20s} model solves per data set by stage: {per}")
        for form, _ in forms[1:]:
            ratio = times[form] / times["standard"]
            ratios.append((name, form, ratio))
            if args.profiles:
                pr = ptimes[form] / ptimes["standard"]
                print(f"random_forces {name} {form}/standard profile time ratio: {pr:.2f}")
    print(f"load averages at the end: {os.getloadavg()}")
    for name, form, ratio in ratios:
        print(f"random_forces {name} {form}/standard fit time ratio: {ratio:.2f}")


if __name__ == "__main__":
    main()
