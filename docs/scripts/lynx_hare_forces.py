"""The figures and numbers of docs/ode.md: Lotka-Volterra calibrated to the Hudson Bay
lynx-hare pelts by least squares and by the ECFM, and the force map of what the model
lacks. Writes docs/img/lynx_hare_forces.png.

Run: ``python docs/scripts/lynx_hare_forces.py``.
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ecfm_uq.datasets import lynx_hare  # noqa: E402
from ecfm_uq.inverse import OdeProblem, fit  # noqa: E402
from ecfm_uq.problems.lotka_volterra import jac_eps, jac_y, rhs  # noqa: E402


def main():
    t, data = lynx_hare()
    problem = OdeProblem(rhs, lambda e: e[4:6], t, data, t0=1900, rtol=1e-10, atol=1e-8,
                         jac=(jac_y, jac_eps), names=["a", "b", "c", "d", "hare0", "lynx0"],
                         state_names=["hare", "lynx"])  # fmt: skip
    eps0 = [0.55, 0.028, 0.024, 0.8, 30.0, 4.0]
    ls = fit(problem, eps0)
    print(ls.summary())
    s = float(np.sqrt(2 * ls.loss / (data.size - 6)))
    print(f"residual standard deviation of the standard fit: {s:.3g} thousand pelts")
    ecfm = fit(problem, ls.eps, formulation="ecfm", sigma=s)
    print(ecfm.summary())
    for name, (a, b), z in ecfm.extra["significant_forces"]:
        print(f"  significant force on {name} over [{a:g}, {b:g}]: z = {z:.1f}")
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    tt = np.linspace(1900, 1920, 400)
    for j, name in enumerate(["hare", "lynx"]):
        line = axes[0].plot(t, data[:, j], "o", label=f"{name} (data)")[0]
        axes[0].plot(tt, ls.state(tt)[:, j], "--", color=line.get_color(),
                     label=f"{name}, least squares")  # fmt: skip
        axes[0].plot(tt, ecfm.state(tt)[:, j], "-", color=line.get_color(), alpha=0.6,
                     label=f"{name}, ECFM (model + forces)")  # fmt: skip
    axes[0].set_ylabel("pelts (thousands)")
    axes[0].legend(fontsize="x-small", ncol=3)
    ecfm.forces.plot(ax=axes[1])
    axes[1].set_ylabel("force (thousands / year)")
    axes[1].set_xlabel("year")
    fig.tight_layout()
    out = Path(__file__).resolve().parents[1] / "img" / "lynx_hare_forces.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
