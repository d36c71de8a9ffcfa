#!/usr/bin/env python3
"""Independent reference for `uquad lqr --path straight --speed 1` and
`--path circle --radius 5 --speed 1` on the default profile (config/uquad.toml: 1.55 kg,
integrators x, y, z, theta, weights lqr-Q-uquad.txt and lqr-R.txt).

The trim is found here with SciPy's root finder on the nonlinear model (spec 3.3 with the
true rotation, in a frame turning with the heading), A and B are its Jacobian written out
from spec 4.5, discretised with SciPy's matrix exponential, and the DARE solved with
solve_discrete_are (a Schur-method solver, unrelated to uquad's doubling algorithm).
Writes K_prop_<case>.txt and K_int_<case>.txt beside this script. Run it again only on
purpose:  python3 tests/data/lqr/path_reference.py   (needs numpy and scipy)
"""
import os
import numpy as np
from scipy.linalg import expm, solve_discrete_are
from scipy.optimize import fsolve

here = os.path.dirname(os.path.abspath(__file__))
config = os.path.join(here, "..", "..", "..", "config")

g, m = 9.81, 1.55
ixx = iyy = 0.0232
izz, izzm = 0.0437, 1.54e-5
L, d = 0.29, 0.07
fb1, fb2 = 4.60160135072435e-05, -0.00103822726273726
md1, md2 = 3.4734e-6, -1.3205e-4
thrust = lambda w: fb1 * w**2 + fb2 * w
drag = lambda w: md1 * w**2 + md2 * w


def rot(psi, phi, th):
    cx, sx, cy, sy, cz, sz = np.cos(psi), np.sin(psi), np.cos(phi), np.sin(phi), np.cos(th), np.sin(th)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return rz @ ry @ rx


def f(x, u, rate, pendulum=True):
    """The nonlinear model: position in a frame turning at `rate`, yaw relative to it."""
    psi, phi, th = x[3:6]
    v, w = x[6:9], x[9:12]
    t = thrust(u)
    W = u[0] - u[1] + u[2] - u[3]
    dmg = d * m * g if pendulum else 0.0
    p = rot(psi, phi, th) @ v
    sps, cps, sph, cph = np.sin(psi), np.cos(psi), np.sin(phi), np.cos(phi)
    return np.array([
        p[0] + rate * x[1], p[1] - rate * x[0], p[2],
        w[0] + (w[2] * cps + w[1] * sps) * sph / cph,
        w[1] * cps - w[2] * sps,
        (w[2] * cps + w[1] * sps) / cph - rate,
        v[1] * w[2] - v[2] * w[1] + g * sph,
        v[2] * w[0] - v[0] * w[2] - g * cph * sps,
        v[0] * w[1] - v[1] * w[0] - g * cph * cps + t.sum() / m,
        (w[1] * w[2] * (iyy - izz) + w[1] * izzm * W + L * (t[1] - t[3]) - dmg * cph * sps) / ixx,
        (w[0] * w[2] * (izz - ixx) + w[0] * izzm * W + L * (t[2] - t[0]) - dmg * sph) / iyy,
        -(drag(u[0]) - drag(u[1]) + drag(u[2]) - drag(u[3])) / izz,
    ])


def trim(speed, rate):
    """Unknowns ψ, φ, w1..w4; the world velocity is (speed, 0, 0) along the nose, the body
    rates those of a yaw rate `rate`. Steady: rows 6..11 vanish (a coordinated turn: no
    pendulum torque)."""
    def state(z):
        psi, phi = z[0], z[1]
        x = np.zeros(12)
        x[3], x[4] = psi, phi
        x[6:9] = rot(psi, phi, 0).T @ np.array([speed, 0, 0])
        x[9:12] = rate * np.array([-np.sin(phi), np.cos(phi) * np.sin(psi), np.cos(phi) * np.cos(psi)])
        return x
    w0 = (-fb2 + np.sqrt(fb2**2 + fb1 * g * m)) / (2 * fb1)
    z = fsolve(lambda z: f(state(z), z[2:], rate, pendulum=False)[6:12],
               [0, 0, w0, w0, w0, w0], xtol=1e-14)
    return state(z), z[2:]


def jacobian(x0, u0, rate):
    """A and B written out (spec 4.5 rows 3..11; rows 0..2 of the true rotation)."""
    psi, phi = x0[3], x0[4]
    vx, vy, vz = x0[6:9]
    wx, wy, wz = x0[9:12]
    sps, cps, sph, cph = np.sin(psi), np.cos(psi), np.sin(phi), np.cos(phi)
    tph = sph / cph
    W = u0[0] - u0[1] + u0[2] - u0[3]
    A = np.zeros((12, 12))
    A[0:3, 6:9] = rot(psi, phi, 0)
    A[0, 3] = vy * sph * cps - vz * sps * sph
    A[1, 3] = -vy * sps - vz * cps
    A[2, 3] = vy * cph * cps - vz * cph * sps
    A[0, 4] = -vx * sph + vy * cph * sps + vz * cps * cph
    A[2, 4] = -vx * cph - vy * sph * sps - vz * sph * cps
    A[0, 5] = -(cps * vy - sps * vz)
    A[1, 5] = cph * vx + sph * sps * vy + cps * sph * vz
    A[0, 1], A[1, 0] = rate, -rate
    A[3, 3] = wy * cps * tph - wz * sps * tph
    A[3, 4] = (wz * cps + wy * sps) * (tph**2 + 1)
    A[3, 9], A[3, 10], A[3, 11] = 1, sps * tph, cps * tph
    A[4, 3], A[4, 10], A[4, 11] = -wy * sps - wz * cps, cps, -sps
    A[5, 3] = (wy * cps - wz * sps) / cph
    A[5, 4] = (wy * sps + wz * cps) * sph / cph**2
    A[5, 10], A[5, 11] = sps / cph, cps / cph
    A[6, 4], A[6, 7], A[6, 8], A[6, 10], A[6, 11] = g * cph, wz, -wy, -vz, vy
    A[7, 3], A[7, 4], A[7, 6], A[7, 8], A[7, 9], A[7, 11] = -g * cps * cph, g * sps * sph, -wz, wx, vz, -vx
    A[8, 3], A[8, 4], A[8, 6], A[8, 7], A[8, 9], A[8, 10] = g * sps * cph, g * cps * sph, wy, -wx, -vy, vx
    A[9, 3] = -d * m * g * cph * cps / ixx
    A[9, 4] = d * m * g * sph * sps / ixx
    A[9, 10] = (izzm * W + (iyy - izz) * wz) / ixx
    A[9, 11] = (iyy - izz) * wy / ixx
    A[10, 4] = -d * m * g * cph / iyy
    A[10, 9] = (izzm * W + (izz - ixx) * wz) / iyy
    A[10, 11] = (izz - ixx) * wx / iyy
    dt, dd = 2 * fb1 * u0 + fb2, 2 * md1 * u0 + md2
    B = np.zeros((12, 4))
    B[8] = dt / m
    B[9] = np.array([wy * izzm, -wy * izzm + L * dt[1], wy * izzm, -wy * izzm - L * dt[3]]) / ixx
    B[10] = np.array([wx * izzm - L * dt[0], -wx * izzm, wx * izzm + L * dt[2], -wx * izzm]) / iyy
    B[11] = np.array([-dd[0], dd[1], -dd[2], dd[3]]) / izz
    # The written-out Jacobian agrees with finite differences of the model.
    h = 1e-6
    for j in range(16):
        xp, xm, up, um = x0.copy(), x0.copy(), u0.copy(), u0.copy()
        if j < 12:
            xp[j] += h
            xm[j] -= h
        else:
            up[j - 12] += h
            um[j - 12] -= h
        col = (f(xp, up, rate) - f(xm, um, rate)) / (2 * h)
        ours = A[:, j] if j < 12 else B[:, j - 12]
        assert np.allclose(col, ours, atol=1e-6), (j, col, ours)
    return A, B


Q = np.loadtxt(os.path.join(config, "lqr-Q-uquad.txt"))
R = np.loadtxt(os.path.join(config, "lqr-R.txt"))
for case, speed, rate in [("straight_v1", 1.0, 0.0), ("circle_r5_v1", 1.0, 1.0 / 5.0)]:
    x0, u0 = trim(speed, rate)
    assert np.abs(f(x0, u0, rate, pendulum=False)[6:]).max() < 1e-10
    A, B = jacobian(x0, u0, rate)
    Ae = np.zeros((16, 16))
    Ae[:12, :12] = A
    for k, s in enumerate([0, 1, 2, 5]):  # x, y, z, theta
        Ae[12 + k, s] = 1
    Be = np.zeros((16, 4))
    Be[:12] = B
    M = np.zeros((20, 20))
    M[:16, :16], M[:16, 16:] = Ae * 0.01, Be * 0.01
    E = expm(M)
    Phi, Gam = E[:16, :16], E[:16, 16:]
    P = solve_discrete_are(Phi, Gam, Q, R)
    K = np.linalg.solve(R + Gam.T @ P @ Gam, Gam.T @ P @ Phi)
    np.savetxt(os.path.join(here, f"K_prop_{case}.txt"), K[:, :12], fmt="%.17e", delimiter="\t")
    np.savetxt(os.path.join(here, f"K_int_{case}.txt"), K[:, 12:], fmt="%.17e", delimiter="\t")
    rho = max(abs(np.linalg.eigvals(Phi - Gam @ K)))
    print(case, "roll", np.degrees(x0[3]), "motors", u0, "spectral radius", rho)
