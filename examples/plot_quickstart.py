"""
Quickstart: EKF vs UKF vs the optimal filter on the cubic sensor
================================================================

The cubic sensor ``x[k+1] = 0.99 x + w``, ``y = x³ + v`` is the classic failure of the extended
Kalman filter: the slope of ``h`` vanishes at ``x = 0``, so the linearization at the mean loses the
sign of the state. :func:`nlfilter.compare` runs the filters on one shared simulation (common
random numbers) beside a certified near-optimal reference (here a grid filter) and reports each
filter's MSE, its paired gap to the optimal MSE, the NEES and the divergence rate.
"""

import matplotlib.pyplot as plt
import sympy as sp

from nlfilter import DiscreteModel, compare
from nlfilter.filters import EKF, UKF

x = sp.Symbol("x")
model = DiscreteModel([x], f=[0.99 * x], h=[x**3], Q=0.01, R=0.1)

res, sim, est = compare(model, {"ekf": EKF(model), "ukf": UKF(model)}, 200, paths=100, m0=0.5, P0=0.1,
                        rng=0, full_output=True)
print(res.table())

# %%
# The reference certified itself: a finer grid on a subset of paths moved its MSE by less than
# the tolerance.
print(res.params["reference"]["label"], res.params["reference"]["kind"])

# %%
# The MSE per step of each filter, with ± 2 standard-error bands from the Monte Carlo paths
# (``res.series`` holds the same curves that :func:`nlfilter.plots.plot_result` draws).
(panel,) = res.series.values()
fig, ax = plt.subplots(figsize=(7, 4))
for name, line in panel["lines"].items():
    ax.plot(panel["x"], line, label=name, color="k" if name == "optimal" else None)
    if name in panel.get("bands", {}):
        lo, hi = panel["bands"][name]
        ax.fill_between(panel["x"], lo, hi, alpha=0.2)
ax.set_yscale("log")
ax.set_xlabel("step k")
ax.set_ylabel("mean square error of x")
ax.legend()

# %%
# One path: the EKF follows the wrong sign for a while, the UKF does not.
fig, ax = plt.subplots(figsize=(7, 3.5))
ax.plot(sim.xs[0, :, 0], "k", label="state x")
for name in ("ekf", "ukf"):
    ax.plot(est[name].means[0, :, 0], label=name)
ax.set_xlabel("step k")
ax.legend()
plt.show()
