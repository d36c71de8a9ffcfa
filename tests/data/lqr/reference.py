#!/usr/bin/env python3
"""Independent reference for `uquad lqr --integrators x,y,z,theta` on the 2012 model.

Builds the hover linearisation of spec 4.5 from its formulas, discretises it with SciPy's
matrix exponential and solves the discrete algebraic Riccati equation with SciPy's
solve_discrete_are (a Schur-method solver, unrelated to uquad's doubling algorithm). Writes
K_prop_xyzt.txt and K_int_xyzt.txt beside this script. Run it again only on purpose:
    python3 tests/data/lqr/reference.py   (needs numpy and scipy)
"""
import os
import numpy as np
from scipy.linalg import expm, solve_discrete_are

here = os.path.dirname(os.path.abspath(__file__))
config = os.path.join(here, "..", "..", "..", "config")

g, m = 9.81, 1.55
ixx = iyy = 0.0232
izz = 0.0437
L, d = 0.29, 0.07
fb1, fb2 = 4.60160135072435e-05, -0.00103822726273726
md1, md2 = 3.4734e-6, -1.3205e-4
w = (-fb2 + np.sqrt(fb2**2 + 4 * fb1 * g * m / 4)) / (2 * fb1)

A = np.zeros((12, 12))
A[0, 6] = A[1, 7] = A[2, 8] = 1
A[3, 9] = A[4, 10] = A[5, 11] = 1
A[6, 4] = g
A[7, 3] = -g
A[9, 3] = -d * m * g / ixx
A[10, 4] = -d * m * g / iyy
B = np.zeros((12, 4))
dt, dq = 2 * fb1 * w + fb2, 2 * md1 * w + md2
B[8, :] = dt / m
B[9, 1], B[9, 3] = L * dt / ixx, -L * dt / ixx
B[10, 0], B[10, 2] = -L * dt / iyy, L * dt / iyy
B[11, :] = [-dq / izz, dq / izz, -dq / izz, dq / izz]

Ae = np.zeros((16, 16))
Ae[:12, :12] = A
for k, s in enumerate([0, 1, 2, 5]):  # x, y, z, theta
    Ae[12 + k, s] = 1
Be = np.zeros((16, 4))
Be[:12, :] = B

M = np.zeros((20, 20))
M[:16, :16] = Ae * 0.01
M[:16, 16:] = Be * 0.01
E = expm(M)
Phi, Gam = E[:16, :16], E[:16, 16:]

Q = np.loadtxt(os.path.join(config, "lqr-Q.txt"))
R = np.loadtxt(os.path.join(config, "lqr-R.txt"))
P = solve_discrete_are(Phi, Gam, Q, R)
K = np.linalg.solve(R + Gam.T @ P @ Gam, Gam.T @ P @ Phi)
np.savetxt(os.path.join(here, "K_prop_xyzt.txt"), K[:, :12], fmt="%.17e", delimiter="\t")
np.savetxt(os.path.join(here, "K_int_xyzt.txt"), K[:, 12:], fmt="%.17e", delimiter="\t")
rho = max(abs(np.linalg.eigvals(Phi - Gam @ K)))
print("closed-loop spectral radius", rho)
