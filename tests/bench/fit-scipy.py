# SPDX-License-Identifier: GPL-3.0-or-later
"""The baseline of the fit benchmark: the script a user would write with
NumPy and SciPy to fit the same points to an even asphere (5 DOF: shift and
tilt, the residual along z), from reading the CSV to printing the pose.

Usage: fit-scipy.py POINTS.csv R k A4 A6 A8 A10 A12
"""
import sys

import numpy as np
from scipy.optimize import least_squares


def main():
    path = sys.argv[1]
    R, k, *A = (float(v) for v in sys.argv[2:])
    p = np.loadtxt(path, delimiter=",", skiprows=1)
    c = 1.0 / R

    def sag(r2):
        z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
        for i, a in enumerate(A):
            z += a * r2 ** (i + 2)
        return z

    def residual(v):
        tx, ty, tz, rx, ry = v
        cx, sx, cy, sy = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry)
        # p = Ry Rx q + t, so q = (Ry Rx)^T (p - t), row by row d @ (Ry Rx)
        m = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ \
            np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        q = (p - (tx, ty, tz)) @ m
        return q[:, 2] - sag(q[:, 0] ** 2 + q[:, 1] ** 2)

    fit = least_squares(residual, np.zeros(5), x_scale=[1e-2, 1e-2, 1e-2, 1e-4, 1e-4])
    rms_nm = 1e6 * np.sqrt(np.mean(fit.fun ** 2))
    print("scipy: %d points, %d evaluations, rms %.3f nm, tx %.3e mm, ry %.3e rad"
          % (len(p), fit.nfev, rms_nm, fit.x[0], fit.x[4]))
    return 0 if fit.success else 1


if __name__ == "__main__":
    sys.exit(main())
