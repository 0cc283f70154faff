"""The eps search of the random-force ECFM: its profiled marginal likelihood minimized.

:class:`Search` minimizes :math:`p(\\epsilon) = \\ell(\\epsilon, \\hat\\tau(\\epsilon))`
(:mod:`~ecfm_uq.inverse.formulations.random_forces`) in coordinates scaled by the standard
fit's standard errors, with the exact gradient
(:mod:`~ecfm_uq.inverse.formulations.random_force_gradient`): where :math:`\\hat\\tau > 0`
at the start already (shared prior, more than one free parameter, no bounds), Fisher
scoring -- steps in the profiled expected information, recomputed at every point from what
the gradient's solve already has, no Hessian by differences
(:mod:`~ecfm_uq.inverse.formulations.random_force_scoring`) -- until its next step is
below 1e-6 standard errors; where scoring does not descend, BFGS from the Hessian at the
start, else L-BFGS-B with restarts. Then, where :math:`\\hat\\tau > 0` (a long flat valley
where a small gradient does not mean close), Newton steps with the Hessian by differences
of the gradient until a step is below 1e-6 standard errors (not after scoring ended at its
tolerance: its own steps are Newton's in the expected information, which then gives the
uncertainty, :func:`~ecfm_uq.inverse.formulations.random_force_scoring.expected_uncertainty`,
from ``res.information``); Nelder-Mead from a wide
simplex where they do not get there, unless the Gauss-Newton information is singular there
(a minimum at infinity, reported so by the fit: the simplex would only walk along the flat
direction). Cheaper cases (issue 37 item 5, shared prior): the standard estimate itself
where :math:`\\hat\\tau = 0` there with a margin (:meth:`Search._standard_optimum`), a
scalar search for one free parameter (:meth:`Search._scalar`).

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

from ..core.convergence import scaled_gradient_optimality
from ..statistics.diagnostics import fd_hessian
from .random_force_scoring import FAILURES, gauss_newton_information, score, singular

__all__ = ["FAILURES", "Search"]

_RESTARTS = 5  # L-BFGS-B restarts of the eps search after a stalled line search
_NEWTON_STEPS = 20  # Newton steps finishing the eps search where tau > 0
_VALLEY_STEPS = (2.0, -2.0, 5.0, -5.0)  # shifts along the valley, standard errors
_VALLEY_ROUNDS = 3  # re-centred on a lower point at most this many times
_FLOOR_STEPS = 1  # Newton steps across the valley from a probe
_PROBES_DESCENDED = 2  # probes descended to a minimum, the lowest on the floor
_DISTINCT = 0.5  # minima farther apart than this (standard errors) are distinct
_NEWTON_TOL = 1e-6  # a Newton step below this (standard errors) ends the finish
_CENTRAL = 1e-3  # after a step below this the next Hessian is the uncertainty's (central)
_HESSIAN_STEP = 1e-3  # the central Hessian's step: the delta method's (_uncertainty)
_SECOND_START_STEPS = 8  # scoring steps from the second start (past a flat end)
_SCALAR_TOL = 1e-6  # the scalar search's root of p' to this (standard errors)
_BRACKET_STEPS = 30  # expansions (or halvings after a failed solve) looking for a bracket


def _armijo(p, x, step, val, slope):
    """Backtracking from the full ``step``: ``(t, p(x + t step))`` at the first halving
    where ``p`` falls by 1e-4 of the linear prediction ``t * slope`` below ``val``, or
    ``None`` once ``t`` is below 1e-3."""
    t = 1.0
    while True:
        trial = p(x + t * step)
        if trial <= val + 1e-4 * t * slope:
            return t, trial
        t *= 0.5
        if t < 1e-3:
            return None


class Search:
    """Minimizes the profiled marginal likelihood over eps in scaled coordinates
    ``x = (eps - eps_std) / scale``: L-BFGS-B with its exact gradient and restarts,
    finished by Newton steps where tau > 0 (:meth:`run`; the sparse prior:
    :meth:`run_sparse`)."""

    def __init__(self, eps_std, scale, bnds, maxiter, tol):
        self.eps_std, self.scale, self.bnds = eps_std, scale, bnds
        self.maxiter, self.tol, self.nfev = maxiter, tol, 0
        self.winner = None  # where run_sparse's estimate came from

    def optimal(self, g, x):
        """Whether the gradient ``g`` at the scaled point ``x`` meets the status test
        (:func:`~ecfm_uq.inverse.core.convergence.scaled_gradient_optimality`)."""
        return scaled_gradient_optimality(g, x, self.bnds, tol=self.tol).converged

    def objective(self, model, count=True, second=False):
        """The profiled nll in ``x`` (``inf`` where the model cannot be solved); with
        ``second`` evaluated with the gradient's second derivatives (a Newton trial point
        that is accepted is the next step's gradient: one solve, not two)."""

        def p(x):
            self.nfev += count
            eps = self.eps_std + self.scale * x
            try:
                return model.profiled_gradient(eps)[0] if second else model.profiled(eps)[0]
            except FAILURES:
                return np.inf

        return p

    def gradient(self, model):
        """The exact gradient of :meth:`objective` in ``x``; raises the model's error."""

        def grad(x):
            return model.profiled_gradient(self.eps_std + self.scale * x)[1] * self.scale

        return grad

    def run(self, model, x0, least_squares_optimum=False, also=None):
        """``(x, res)`` from ``x0``; ``res.fun`` the profiled nll at ``x``.

        ``also``: a second start (the user's ``eps0``, scaled) for where the search ends
        where the Gauss-Newton information is singular: a standard fit that ran a
        parameter off to where it has no effect anchors nothing, and the profiled
        likelihood may have a minimum inside (the coverage study's operator data set 150:
        0.026 lower at eps0 = -0.09 than at the flat end, -12.6). Fisher scoring from it;
        where that reaches a lower point, the search from there, the lower kept.

        ``least_squares_optimum``: ``x0`` is the standard fit's estimate and its optimality
        conditions were measured to hold there; then, where tau-hat is 0 there with a
        strict margin and the measured gradient of the profiled likelihood is below the
        tolerance, ``x0`` is returned after that one evaluation (:meth:`_standard_optimum`).
        One free parameter (shared prior): a scalar search (:meth:`_scalar`); more,
        unbounded, with tau-hat > 0 at ``x0``: Fisher scoring
        (:func:`~ecfm_uq.inverse.formulations.random_force_scoring.score`), where it does
        not descend BFGS from the Hessian there (:meth:`_quasi_newton`), instead of
        L-BFGS-B, then the Newton finish."""
        if least_squares_optimum:
            res = self._standard_optimum(model, x0)
            if res is not None:
                return np.array(x0, float), res
        if np.size(x0) == 1 and model.prior == "shared":
            found = self._scalar(model, x0)
            if found is not None:
                return found
        found = None
        if model.prior == "shared" and self.bnds is None and np.size(x0) > 1:
            scored = score(self, model, x0, _armijo)
            if scored is not None:
                # at scoring's tolerance (tau-hat > 0 there): no Newton check by the
                # central Hessian (2 x.size solves); the uncertainty is the expected
                # information there (res.information, random_force_scoring.
                # expected_uncertainty) and the status the gradient measured there by the fit
                return scored[:2]
            found = self._quasi_newton(model, x0)
        x, res = found if found is not None else self._descend(model, x0)
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
            x_n, val_n, steps, done = self._newton(
                self.objective(model, second=True), self.gradient(model), x, res.fun
            )
            res.nit += steps
            if done:
                res.fun, res.success = val_n, True
                return x_n, res
        if finish and np.isfinite(res.fun) and self._flat(model, x):
            # the readings do not depend on some parameter combination here (the fit's own
            # test of a minimum at infinity, which then reports it not converged): a
            # simplex only walks along that flat direction (the reaction rod: 186
            # evaluations for a drop of 1e-14, rounding, 1e-14 standard errors away);
            # scoring from the second start instead (a few solves)
            if also is not None and np.all(np.isfinite(also)) and np.any(also != x):
                # lower beyond rounding (the flat end's own values differ by ~1e-14)
                lower = res.fun - 1e-9 * abs(res.fun)
                budget, self.maxiter = self.maxiter, _SECOND_START_STEPS
                try:  # a probe: scoring takes 3-7 steps to a minimum (module docstring)
                    scored = score(self, model, also, _armijo)
                finally:
                    self.maxiter = budget
                if scored is not None and scored[1].fun < lower:
                    x_b, res_b = self.run(model, scored[0])
                    if np.isfinite(res_b.fun) and res_b.fun < lower:
                        return x_b, res_b
            return x, res
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

    def _flat(self, model, x):
        """Whether the Gauss-Newton information :math:`J^T S^{-1} J` is singular at ``x``
        (:func:`~ecfm_uq.inverse.formulations.random_force_scoring.singular`)."""
        try:
            _, g_hat, lin = model.profiled(self.eps_std + self.scale * x)
            return singular(gauss_newton_information(model, lin, g_hat))
        except FAILURES:
            return False

    def _standard_optimum(self, model, x0):
        """The standard estimate ``x0`` as the estimate, or ``None`` (search on).

        Where tau-hat is 0 at :math:`\\epsilon_0` with a strict margin -- the restricted
        likelihood's drop :math:`2(\\ell_R(0) - \\ell_R(s))` negative at every grid point
        :math:`s > 0` (so ``best_s`` returns 0) and its slope at :math:`s = 0` negative (the
        restricted nll increasing in :math:`\\tau^2` there) -- the drop is continuous in
        :math:`\\epsilon` (it is a spectral function of :math:`Q A A^T Q` and of
        :math:`Q r`, :math:`Q` the projector onto the complement of :math:`J`'s span,
        continuous while :math:`J` keeps its rank), so it stays negative on the grid in a
        neighbourhood, tau-hat stays 0 there and the profiled likelihood equals the
        standard likelihood :math:`\\tfrac12\\|r\\|^2/\\sigma^2` (+ a constant) there.
        The standard fit measured its optimality conditions to hold at :math:`\\epsilon_0`:
        a local minimum of that, hence of the profiled likelihood. L-BFGS-B from there
        would only shuffle within the status tolerance; the status itself still comes from
        the gradient of the profiled likelihood measured here (and again by the caller)."""
        try:
            val, g = model.profiled_gradient(self.eps_std + self.scale * x0)
            zero = model.tau_strictly_zero(self.eps_std + self.scale * x0)
        except FAILURES:
            return None
        self.nfev += 1
        if not zero or not self.optimal(g * self.scale, x0):
            return None
        return optimize.OptimizeResult(
            x=np.array(x0, float), fun=val, nit=0, njev=1, success=True,
            message="tau-hat = 0 with a margin at the standard estimate, a least-squares "
            "optimum: a local minimum of the profiled likelihood",
        )  # fmt: skip

    def _scalar(self, model, x0):
        """One free parameter: ``(x, res)``, or ``None`` where the scalar search cannot
        tell (a solve failing throughout, no bracket) and the general search takes over.

        The exact derivative :math:`p'` is followed downhill from ``x0`` (the first step
        by the Gauss-Newton curvature :math:`J^T S^{-1} J`, then secant steps, expanding)
        until it changes sign, which brackets a minimum, or a bound holds it (a derivative
        pointing out of the box there: the bound is the optimum); then secant steps on
        :math:`p'` kept inside the bracket by bisection (:meth:`_root`) until a step is
        below ``_SCALAR_TOL`` standard errors (superlinear, bracketed: no line search, no
        quasi-Newton memory, no Hessian by differences). A root whose value is not below the bracket's ends (a maximum
        between two minima) is refused."""
        lo, hi = -np.inf, np.inf
        if self.bnds is not None:
            lo = -np.inf if self.bnds[0][0] is None else float(self.bnds[0][0])
            hi = np.inf if self.bnds[0][1] is None else float(self.bnds[0][1])
        evals = {"n": 0}

        def at(x):
            self.nfev += 1
            evals["n"] += 1
            return model.profiled_gradient(self.eps_std + self.scale * np.array([x]))

        def result(x, val, message):
            return np.array([x]), optimize.OptimizeResult(
                x=np.array([x]), fun=val, nit=evals["n"], njev=evals["n"], success=True,
                message=message,
            )  # fmt: skip

        a = float(np.ravel(x0)[0])
        try:
            va, ga = at(a)
            _, g_hat, lin = model.profiled(self.eps_std + self.scale * np.array([a]))
        except FAILURES:
            return None
        ga = float(ga[0]) * float(self.scale[0])
        if ga == 0.0:
            return result(a, va, "scalar search: p' = 0 at the start")
        info = float(lin.J[:, 0] @ np.linalg.solve(model.covariance(lin, g_hat), lin.J[:, 0]))
        curv = info * float(self.scale[0]) ** 2
        step = -ga / curv if np.isfinite(curv) and curv > 0 else -ga
        for _ in range(_BRACKET_STEPS):
            b = float(np.clip(a + step, lo, hi))
            if b == a:  # at a bound with p' pointing out of the box: the bound holds it
                return result(a, va, "scalar search: at a bound, p' pointing out")
            try:
                vb, gb = at(b)
            except FAILURES:
                step *= 0.5  # back towards the last point that solves
                continue
            gb = float(gb[0]) * float(self.scale[0])
            if not np.isfinite(gb):
                return None
            if np.sign(gb) != np.sign(ga):
                break
            if b in (lo, hi):  # still descending at the bound
                return result(b, vb, "scalar search: at a bound, p' pointing out")
            slope = (gb - ga) / (b - a)
            # secant steps towards the root of p', between 1 and 8 times the last step
            span = b - a
            if slope > 0:
                step = float(np.clip(-gb / slope, min(span, 8 * span), max(span, 8 * span)))
            else:
                step = 4.0 * span
            a, va, ga = b, vb, gb
        else:
            return None
        try:
            x, val, steps = self._root(at, (a, va, ga), (b, vb, gb))
        except FAILURES:
            return None
        if x is None or not val <= min(va, vb):
            return None
        return result(x, val, f"scalar search: p' = 0 bracketed, {steps} secant steps")

    def _root(self, at, one, two):
        """Root of :math:`p'` between ``one`` and ``two`` (``(x, p, p')`` each, the
        derivatives of opposite signs): secant steps on the last two points, bisection
        where a step leaves the bracket or the bracket does not halve in three steps;
        ``(x, p(x), steps)`` once a step would move less than ``_SCALAR_TOL`` (``x`` is
        evaluated: its derivative is measured), ``(None, inf, steps)`` after 60."""
        lo, hi = (one, two) if one[0] < two[0] else (two, one)  # p' differs in sign
        prev, cur = one, two
        width, slow = hi[0] - lo[0], 0
        for k in range(60):
            if cur[2] == 0.0:
                return cur[0], cur[1], k
            x = np.nan
            if cur[2] != prev[2]:
                x = cur[0] - cur[2] * (cur[0] - prev[0]) / (cur[2] - prev[2])
            if not lo[0] < x < hi[0] or slow >= 3:
                x, slow, width = 0.5 * (lo[0] + hi[0]), 0, hi[0] - lo[0]
            if abs(x - cur[0]) < _SCALAR_TOL:
                return cur[0], cur[1], k
            val, g = at(x)
            new = (x, val, float(g[0]) * float(self.scale[0]))
            if np.sign(new[2]) == np.sign(lo[2]):
                lo = new
            else:
                hi = new
            slow = slow + 1 if hi[0] - lo[0] > 0.5 * width else 0
            if slow == 0:
                width = hi[0] - lo[0]
            prev, cur = cur, new
        return None, np.inf, 60

    def _quasi_newton(self, model, x0):
        """Where tau-hat > 0 at ``x0`` already: BFGS from the Hessian there (forward
        differences of the exact gradient, ``x0.size`` solves), Armijo backtracking,
        until the gradient meets the tolerance: ``(x, res)``, or ``None`` (L-BFGS-B then).

        The profiled likelihood's valley (the discrepancy trading off against eps) is
        ill-conditioned in standard-error units (Hessian eigenvalues 0.4 and 300 on the
        reaction rod): L-BFGS-B's unit first step went far up its side and crept back
        along it (~7 evaluations); from the Hessian at the start the first step is
        Newton's and the secant updates keep the metric."""
        eps = self.eps_std + self.scale * x0
        grad = self.gradient(model)
        try:
            val = model.profiled_gradient(eps)[0]
            if not (np.isfinite(val) and np.any(model.profiled(eps)[1])):
                return None
            x = np.array(x0, float)
            g = grad(x)
            H = np.column_stack([(grad(x + 1e-4 * e) - g) / 1e-4 for e in np.eye(x.size)])
        except FAILURES:
            return None
        self.nfev += 1 + x.size
        H = 0.5 * (H + H.T)
        w = np.linalg.eigvalsh(H)
        if not (np.all(np.isfinite(w)) and w[0] > 1e-12 * abs(w[-1]) and w[0] > 0):
            return None
        Hinv = np.linalg.inv(H)
        p = self.objective(model, second=True)
        for k in range(self.maxiter):
            if self.optimal(g, x):
                return x, optimize.OptimizeResult(
                    x=x, fun=val, nit=k, njev=k + 1, success=True,
                    message=f"BFGS from the Hessian at the standard estimate ({k} steps)",
                )  # fmt: skip
            step = -Hinv @ g
            found = _armijo(p, x, step, val, float(g @ step))
            if found is None:
                return None
            t, trial = found
            try:
                g_new = grad(x + t * step)  # remembered: no solve
            except FAILURES:
                return None
            sk, yk = t * step, g_new - g
            if float(sk @ yk) > 1e-12 * float(np.linalg.norm(sk) * np.linalg.norm(yk)):
                rho = 1.0 / float(sk @ yk)
                V = np.eye(x.size) - rho * np.outer(sk, yk)
                Hinv = V @ Hinv @ V.T + rho * np.outer(sk, sk)
            x, val, g = x + t * step, trial, g_new
        return None

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
            if g is not None and g.size and self.optimal(g, intermediate_result.x):
                last["stopped"] = True
                raise StopIteration

        nit, njev, maxiter = 0, 0, self.maxiter
        for _ in range(_RESTARTS):
            # the standard errors of a consistent fit can be a poor scale once tau > 0
            # (the optimum may lie many of them away): a stalled line search restarts
            # from where it stopped, with a fresh quasi-Newton memory
            last["stopped"] = False
            res = optimize.minimize(
                fun, x, jac=True, method="L-BFGS-B", bounds=self.bnds,
                callback=stop_when_optimal,
                options={"maxiter": maxiter - nit, "ftol": 1e-10, "gtol": 1e-6},
            )  # fmt: skip
            if last["stopped"]:  # our test's stop, in our words, not scipy's StopIteration
                res.message = "L-BFGS-B stopped by the gradient test (standard-error units)"
            if last["g"] is not None and self.optimal(last["g"], res.x):
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
        x_n, val_n, steps, done = self._newton(self.objective(model, second=True), grad, x, res.fun)
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

    def _newton(self, p, grad, x, val, last=np.inf):
        """Newton steps on the exact gradient ``grad``, the Hessian by differences of it,
        with backtracking on ``p``: ``(x, value, steps, converged)``, converged when a step
        is below ``_NEWTON_TOL`` (the scaled coordinates: standard errors). ``x`` is
        returned without that last step: its gradient is the one measured.

        The Hessian is by forward differences (``x.size`` gradients) while the steps are
        long; after a step below ``_CENTRAL`` (the next step is likely below the
        tolerance, Newton converging quadratically) it is the delta method's central
        differences of step ``_HESSIAN_STEP`` (``2 x.size`` gradients): the model
        remembers those points, so the uncertainty at the estimate costs no solve.
        ``last``: the length of the step that reached ``x`` (a search's last, below
        ``_CENTRAL``: the first Hessian is the central one)."""
        x = np.array(x, float)
        for k in range(_NEWTON_STEPS):
            try:
                g = grad(x)
                if last < _CENTRAL:
                    H = fd_hessian(grad, x, _HESSIAN_STEP)
                    self.nfev += 2 * x.size
                else:
                    # forward differences of the exact gradient: the Hessian only steers
                    # the steps (their accuracy sets the convergence rate, not the point
                    # reached)
                    H = np.column_stack([(grad(x + 1e-4 * e) - g) / 1e-4 for e in np.eye(x.size)])
                    H = 0.5 * (H + H.T)
                    self.nfev += x.size
            except FAILURES:
                return x, val, k, False
            self.nfev += 1
            w, V = np.linalg.eigh(H)
            if not (np.all(np.isfinite(w)) and w[0] > 1e-12 * abs(w[-1])):
                return x, val, k, False  # not a minimum's neighbourhood: no Newton step
            step = -V @ ((V.T @ g) / w)
            if np.max(np.abs(step)) < _NEWTON_TOL:
                return x, val, k + 1, True
            found = _armijo(p, x, step, val, float(g @ step))
            if found is None:
                return x, val, k + 1, False
            t, trial = found
            x, val, last = x + t * step, trial, t * float(np.max(np.abs(step)))
        return x, val, _NEWTON_STEPS, False
