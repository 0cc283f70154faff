"""The eps search of the random-force ECFM: its profiled marginal likelihood minimized.

:class:`Search` minimizes :math:`p(\\epsilon) = \\ell(\\epsilon, \\hat\\tau(\\epsilon))`
(:mod:`~ecfm_uq.inverse.formulations.random_forces`) in coordinates scaled by the standard
fit's standard errors, with the exact gradient
(:mod:`~ecfm_uq.inverse.formulations.random_force_gradient`): L-BFGS-B with restarts, then,
where :math:`\\hat\\tau > 0` (a long flat valley where a small gradient does not mean
close), Newton steps with the Hessian by differences of the gradient until a step
is below 1e-6 standard errors (shared prior; Nelder-Mead from a wide simplex where they
do not get there).

With a variance per force (:meth:`Search.run_sparse`) the profiled likelihood has local
minima along that valley, forces switching on and off as eps moves along it: descents
from the starts, then probes along the valley's flattest direction, each moved to the
valley's floor by Newton steps across it and the lowest two descended, repeated from a
distinct lower minimum, all on the exact gradient, then the Newton finish. On the
coverage study's discrepancy rows (120 data sets) this reached the previous
Nelder-Mead finish's minimum or a lower one on every data set with ~40 % of its model
solves (``docs/benchmarks.md``).
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from ...errors import ConvergenceError, ModelEvaluationError
from ..core.convergence import scaled_gradient_optimality

__all__ = ["FAILURES", "Search"]

# the model cannot be solved there (ValueError: non-finite parameters after an overflow)
FAILURES = (ConvergenceError, ModelEvaluationError, np.linalg.LinAlgError, ValueError)
_RESTARTS = 5  # L-BFGS-B restarts of the eps search after a stalled line search
_NEWTON_STEPS = 20  # Newton steps finishing the eps search where tau > 0
_VALLEY_STEPS = (2.0, -2.0, 5.0, -5.0)  # shifts along the valley, standard errors
_VALLEY_ROUNDS = 3  # re-centred on a lower point at most this many times
_FLOOR_STEPS = 1  # Newton steps across the valley from a probe
_PROBES_DESCENDED = 2  # probes descended to a minimum, the lowest on the floor
_DISTINCT = 0.5  # minima farther apart than this (standard errors) are distinct


class Search:
    """Minimizes the profiled marginal likelihood over eps in scaled coordinates
    ``x = (eps - eps_std) / scale``: L-BFGS-B with its exact gradient and restarts,
    finished by Newton steps where tau > 0 (:meth:`run`; the sparse prior:
    :meth:`run_sparse`)."""

    def __init__(self, eps_std, scale, bnds, maxiter, tol):
        self.eps_std, self.scale, self.bnds = eps_std, scale, bnds
        self.maxiter, self.tol, self.nfev = maxiter, tol, 0
        self.winner = None  # where run_sparse's estimate came from

    def _optimal(self, g, x):
        return scaled_gradient_optimality(g, x, self.bnds, tol=self.tol).converged

    def objective(self, model, count=True):
        def p(x):
            self.nfev += count
            try:
                return model.profiled(self.eps_std + self.scale * x)[0]
            except FAILURES:
                return np.inf

        return p

    def gradient(self, model):
        """The exact gradient of :meth:`objective` in ``x``; raises the model's error."""

        def grad(x):
            return model.profiled_gradient(self.eps_std + self.scale * x)[1] * self.scale

        return grad

    def run(self, model, x0):
        """``(x, res)`` from ``x0``; ``res.fun`` the profiled nll at ``x``."""
        x, res = self._descend(model, x0)
        tau_positive = np.isfinite(res.fun) and np.any(
            model.profiled(self.eps_std + self.scale * x)[1]
        )
        finish = (tau_positive or not res.success) and self.bnds is None
        p = self.objective(model)
        if finish and model.prior == "shared" and np.isfinite(res.fun):
            # with tau > 0 the optimum lies in a long flat valley (the discrepancy trading
            # off against eps) where a small gradient in standard-error units does not
            # mean close (a premature stop there made the estimate depend on the
            # equations' units): finish by Newton steps until a step is below 1e-6
            # standard errors, derivative-free where they do not get there
            x_n, val_n, steps, done = self._newton(p, self.gradient(model), x, res.fun)
            res.nit += steps
            if done:
                res.fun, res.success = val_n, True
                return x_n, res
        if finish:
            simplex = x + np.vstack([np.zeros(x.size), 10.0 * np.eye(x.size)])
            nm = optimize.minimize(
                p, x, method="Nelder-Mead",
                options={"initial_simplex": simplex, "xatol": 1e-6, "fatol": 1e-12,
                         "maxfev": 400 * max(x.size, 1)},
            )  # fmt: skip
            nit, njev = res.nit + nm.nit, res.njev
            if nm.fun < res.fun:
                x, res = nm.x, nm
                res.success = bool(nm.success)
            res.nit, res.njev = nit, njev
        return x, res

    def _descend(self, model, x0):
        """L-BFGS-B on the exact gradient from ``x0``, restarted after a stalled line
        search: ``(x, res)``, ``res.nit`` and ``res.njev`` summed over the restarts."""
        try:  # with its second derivatives: the search's first point is usually this one
            nll0 = model.profiled_gradient(self.eps_std)[0]
        except FAILURES:
            nll0 = np.inf
        base, x = nll0, np.array(x0, float)
        last = {"g": None}

        def fun(x):
            self.nfev += 1
            try:
                val, g = model.profiled_gradient(self.eps_std + self.scale * x)
            except FAILURES:
                return base + 1e12, np.zeros(x.size)
            last["g"] = g * self.scale
            return val, last["g"]

        def stop_when_optimal(intermediate_result):
            # our own criterion, not the optimizer's (its ftol on a finite-difference
            # gradient behaves differently across scipy versions): the gradient in
            # standard-error units (convergence.scaled_gradient_optimality) leaves eps
            # within that fraction of a standard error
            g = last["g"]
            if g is not None and g.size and self._optimal(g, intermediate_result.x):
                raise StopIteration

        nit, njev, maxiter = 0, 0, self.maxiter
        for _ in range(_RESTARTS):
            # the standard errors of a consistent fit can be a poor scale once tau > 0
            # (the optimum may lie many of them away): a stalled line search restarts
            # from where it stopped, with a fresh quasi-Newton memory
            res = optimize.minimize(
                fun, x, jac=True, method="L-BFGS-B", bounds=self.bnds,
                callback=stop_when_optimal,
                options={"maxiter": maxiter - nit, "ftol": 1e-10, "gtol": 1e-6},
            )  # fmt: skip
            if last["g"] is not None and self._optimal(last["g"], res.x):
                res.success = True
            moved = np.max(np.abs(res.x - x)) if x.size else 0.0
            nit, njev = nit + res.nit, njev + res.njev
            if res.fun <= nll0:
                x = res.x
            if res.success or moved < 1e-8 or nit >= maxiter:
                break
        res.nit, res.njev = nit, njev
        return x, res

    def run_sparse(self, model, starts):
        """The sparse prior's search: ``(x, res)``, the lowest of L-BFGS-B descents from
        ``starts`` (scaled coordinates) and, where tau > 0 at the end of one, of descents
        from points along the valley, finished by Newton steps.

        With a variance per force the profiled likelihood has local minima along the
        valley where the discrepancy trades off against eps (forces switching on and
        off). From the lowest point found, probes at ``_VALLEY_STEPS`` standard errors
        along the Hessian's flattest eigenvector are moved to the valley's floor by
        ``_FLOOR_STEPS`` Newton steps across it (the valley is curved: a probe on the
        straight line lies up its side), and the ``_PROBES_DESCENDED`` lowest there are
        descended; a lower minimum farther than ``_DISTINCT`` standard errors away is
        probed around in turn (at most ``_VALLEY_ROUNDS`` times). Every step uses the
        exact gradient (the envelope theorem: the variances maximize the likelihood at
        every eps). ``self.winner`` records where the estimate came from:
        ``"start <k>"`` or ``"valley <round>:<shift>"``.
        """
        found = [(self._descend(model, x0), f"start {k}") for k, x0 in enumerate(starts)]
        (x, res), self.winner = min(found, key=lambda f: f[0][1].fun)
        if not np.isfinite(res.fun) or self.bnds is not None:
            return x, res
        if not any(
            np.isfinite(r.fun) and np.any(model.profiled(self.eps_std + self.scale * xk)[1])
            for (xk, r), _ in found
        ):
            return x, res  # tau = 0 wherever a start ends: least squares, no valley
        grad = self.gradient(model)
        for k in range(_VALLEY_ROUNDS):
            try:
                w, V = self._hessian_eigen(grad, x)
            except FAILURES:
                break
            probes = []
            for t in _VALLEY_STEPS:
                y, val = self._to_floor(model, x + t * V[:, 0], V[:, 1:], w[1:])
                probes.append((val, t, y))
            probes.sort(key=lambda f: f[0])
            best = None
            for val, t, y in probes[:_PROBES_DESCENDED]:
                if not np.isfinite(val):
                    continue
                xt, rt = self._descend(model, y)
                if rt.fun < res.fun and (best is None or rt.fun < best[1].fun):
                    best = (xt, rt, f"valley {k}:{t:g}")
            if best is None:
                break
            distinct = np.max(np.abs(best[0] - x)) > _DISTINCT
            x, res, self.winner = best
            if not distinct:
                break
        # (res.nit: the iterations of the descent that found the estimate and of its
        # finish, as a single search's; self.nfev counts every evaluation)
        x_n, val_n, steps, done = self._newton(self.objective(model), grad, x, res.fun)
        res.nit += steps
        if done and val_n <= res.fun:
            x, res.fun, res.success = x_n, val_n, True
        return x, res

    def _hessian_eigen(self, grad, x):
        """Eigenvalues and eigenvectors of the Hessian at ``x`` (forward differences of
        the exact gradient), ascending."""
        g = grad(x)
        H = np.column_stack([(grad(x + 1e-4 * e) - g) / 1e-4 for e in np.eye(x.size)])
        self.nfev += 1 + x.size
        return np.linalg.eigh(0.5 * (H + H.T))

    def _to_floor(self, model, y, Q, wq):
        """``y`` moved to the valley's floor across it: Newton steps in the directions
        ``Q`` (curvatures ``wq``), ``_FLOOR_STEPS`` of them; ``(y, value there)``."""
        y, val = np.array(y, float), np.inf
        for step in range(_FLOOR_STEPS + 1):
            self.nfev += 1
            try:
                val, g = model.profiled_gradient(self.eps_std + self.scale * y)
            except FAILURES:
                return y, np.inf
            if step == _FLOOR_STEPS or not np.all(wq > 0):
                break
            y = y - Q @ ((Q.T @ (g * self.scale)) / wq)
        return y, val

    def _newton(self, p, grad, x, val):
        """Newton steps on the exact gradient ``grad``, the Hessian by forward differences
        of it, with backtracking on ``p``: ``(x, value, steps, converged)``, converged when
        a step is below 1e-6 (the scaled coordinates: standard errors)."""
        x = np.array(x, float)
        for k in range(_NEWTON_STEPS):
            try:
                g = grad(x)
                # forward differences of the exact gradient: the Hessian only steers the
                # steps (their accuracy sets the convergence rate, not the point reached)
                H = np.column_stack([(grad(x + 1e-4 * e) - g) / 1e-4 for e in np.eye(x.size)])
            except FAILURES:
                return x, val, k, False
            H = 0.5 * (H + H.T)
            self.nfev += 1 + x.size
            w, V = np.linalg.eigh(H)
            if not (np.all(np.isfinite(w)) and w[0] > 1e-12 * abs(w[-1])):
                return x, val, k, False  # not a minimum's neighbourhood: no Newton step
            step = -V @ ((V.T @ g) / w)
            if np.max(np.abs(step)) < 1e-6:
                trial = p(x + step)
                return (x + step, trial, k + 1, True) if trial <= val else (x, val, k + 1, True)
            t = 1.0
            while True:
                trial = p(x + t * step)
                if trial <= val + 1e-4 * t * float(g @ step):
                    break
                t *= 0.5
                if t < 1e-3:
                    return x, val, k + 1, False
            x, val = x + t * step, trial
        return x, val, _NEWTON_STEPS, False
