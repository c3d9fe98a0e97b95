"""Compiled kernels of the shadow renderer (numba): FK, exact point-light projection of convex pieces,
convex hull and scanline fill at pixel centres. Pure compute; ``studio.sim.shadow`` is the public face.

A piece is the convex hull of ``n`` spheres of one radius ``r`` (capsule: 2 centres, sphere: 1, box: its 8
corners with r = 0). Its shadow is the convex hull of the shadows of those spheres; the shadow of a sphere under
a point light is the projection of the sphere's contact circle with its tangent cone from the light (an
ellipse on the backdrop), sampled at ``M`` points scaled to keep the ellipse's area.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, fastmath=False)
def _fk_one(theta, parent, T_origin, axis, T_out):
    """One pose: ``theta (J,)`` → ``T_out (J+1, 4, 4)``; link 0 is the root (identity)."""
    for a in range(4):
        for b in range(4):
            T_out[0, a, b] = 1.0 if a == b else 0.0
    R = np.empty((3, 3))
    for j in range(theta.shape[0]):
        x, y, z = axis[j, 0], axis[j, 1], axis[j, 2]
        c, s = math.cos(theta[j]), math.sin(theta[j])
        C = 1.0 - c
        R[0, 0] = c + x * x * C
        R[0, 1] = x * y * C - z * s
        R[0, 2] = x * z * C + y * s
        R[1, 0] = y * x * C + z * s
        R[1, 1] = c + y * y * C
        R[1, 2] = y * z * C - x * s
        R[2, 0] = z * x * C - y * s
        R[2, 1] = z * y * C + x * s
        R[2, 2] = c + z * z * C
        P = T_out[parent[j]]
        O = T_origin[j]
        child = T_out[j + 1]
        for a in range(3):
            # M = P[:3,:3] @ O[:3,:3]; child rot = M @ R; child pos = P @ O[:, 3]
            m0 = P[a, 0] * O[0, 0] + P[a, 1] * O[1, 0] + P[a, 2] * O[2, 0]
            m1 = P[a, 0] * O[0, 1] + P[a, 1] * O[1, 1] + P[a, 2] * O[2, 1]
            m2 = P[a, 0] * O[0, 2] + P[a, 1] * O[1, 2] + P[a, 2] * O[2, 2]
            for b in range(3):
                child[a, b] = m0 * R[0, b] + m1 * R[1, b] + m2 * R[2, b]
            child[a, 3] = P[a, 0] * O[0, 3] + P[a, 1] * O[1, 3] + P[a, 2] * O[2, 3] + P[a, 3]
        child[3, 0] = 0.0
        child[3, 1] = 0.0
        child[3, 2] = 0.0
        child[3, 3] = 1.0


@njit(cache=True)
def _cross(ox, oy, ax, ay, bx, by):
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@njit(cache=True)
def _convex_hull(px, py, n, hx, hy):
    """Andrew's monotone chain on ``n`` points (sorted in place, no allocation); writes the counter-clockwise
    hull into hx, hy and returns its size."""
    for i in range(1, n):  # insertion sort by (x, y): n <= 8 * M is small
        x, y = px[i], py[i]
        k = i - 1
        while k >= 0 and (px[k] > x or (px[k] == x and py[k] > y)):
            px[k + 1] = px[k]
            py[k + 1] = py[k]
            k -= 1
        px[k + 1] = x
        py[k + 1] = y
    k = 0
    for i in range(n):  # lower hull
        while k >= 2 and _cross(hx[k - 2], hy[k - 2], hx[k - 1], hy[k - 1], px[i], py[i]) <= 0:
            k -= 1
        hx[k] = px[i]
        hy[k] = py[i]
        k += 1
    t = k + 1
    for i in range(n - 2, -1, -1):  # upper hull
        while k >= t and _cross(hx[k - 2], hy[k - 2], hx[k - 1], hy[k - 1], px[i], py[i]) <= 0:
            k -= 1
        hx[k] = px[i]
        hy[k] = py[i]
        k += 1
    return k - 1 if k > 1 else k


@njit(cache=True)
def _fill_convex(img, hx, hy, k, umin_row, umax_row):
    """Set every pixel whose centre (j+0.5, i+0.5) lies inside the convex polygon (hx, hy)[:k] (pixel units)."""
    H, W = img.shape
    if k < 3:
        return
    vlo, vhi = 1e30, -1e30
    for e in range(k):
        vlo = min(vlo, hy[e])
        vhi = max(vhi, hy[e])
    i0 = max(0, int(math.ceil(vlo - 0.5)))
    i1 = min(H - 1, int(math.floor(vhi - 0.5)))
    if i0 > i1:
        return
    for i in range(i0, i1 + 1):
        umin_row[i] = 1e30
        umax_row[i] = -1e30
    for e in range(k):
        ax, ay = hx[e], hy[e]
        bx, by = hx[(e + 1) % k], hy[(e + 1) % k]
        if ay == by:
            continue
        lo, hi = min(ay, by), max(ay, by)
        r0 = max(i0, int(math.ceil(lo - 0.5)))
        r1 = min(i1, int(math.floor(hi - 0.5)))
        for i in range(r0, r1 + 1):
            vc = i + 0.5
            u = ax + (bx - ax) * (vc - ay) / (by - ay)
            umin_row[i] = min(umin_row[i], u)
            umax_row[i] = max(umax_row[i], u)
    for i in range(i0, i1 + 1):
        if umax_row[i] < umin_row[i]:
            continue
        j0 = max(0, int(math.ceil(umin_row[i] - 0.5)))
        j1 = min(W - 1, int(math.floor(umax_row[i] - 0.5)))
        for j in range(j0, j1 + 1):
            img[i, j] = 1


@njit(cache=True)
def _render_one(T, piece_link, piece_pts, piece_n, piece_r, light, zb, half, scale, M, img, px, py, hx, hy, ur, vr):
    """Shadow of one posed hand (link poses ``T (L, 4, 4)``) into ``img (H, W)`` uint8."""
    ring_k = math.sqrt(2 * math.pi / (M * math.sin(2 * math.pi / M)))  # polygon keeps the ellipse's area
    cos_m = np.empty(M)
    sin_m = np.empty(M)
    for m in range(M):
        cos_m[m] = math.cos(2.0 * math.pi * m / M)
        sin_m[m] = math.sin(2.0 * math.pi * m / M)
    Lx, Ly, Lz = light[0], light[1], light[2]
    for p in range(piece_link.shape[0]):
        Tl = T[piece_link[p]]
        r = piece_r[p]
        n = 0
        for q in range(piece_n[p]):
            lx, ly, lz = piece_pts[p, q, 0], piece_pts[p, q, 1], piece_pts[p, q, 2]
            cx = Tl[0, 0] * lx + Tl[0, 1] * ly + Tl[0, 2] * lz + Tl[0, 3]
            cy = Tl[1, 0] * lx + Tl[1, 1] * ly + Tl[1, 2] * lz + Tl[1, 3]
            cz = Tl[2, 0] * lx + Tl[2, 1] * ly + Tl[2, 2] * lz + Tl[2, 3]
            if r <= 0.0:
                s = (Lz - zb) / (Lz - cz)
                px[n] = ((Lx + s * (cx - Lx)) + half) * scale
                py[n] = (half - (Ly + s * (cy - Ly))) * scale
                n += 1
                continue
            vx, vy, vz = cx - Lx, cy - Ly, cz - Lz
            d = math.sqrt(vx * vx + vy * vy + vz * vz)
            ux, uy, uz = vx / d, vy / d, vz / d
            # contact circle of the tangent cone from the light
            ox, oy, oz = cx - ux * r * r / d, cy - uy * r * r / d, cz - uz * r * r / d
            rho = r * math.sqrt(max(d * d - r * r, 0.0)) / d * ring_k
            # orthonormal e1, e2 perpendicular to u
            if abs(ux) < 0.9:
                ax_, ay_, az_ = 1.0, 0.0, 0.0
            else:
                ax_, ay_, az_ = 0.0, 1.0, 0.0
            e1x, e1y, e1z = uy * az_ - uz * ay_, uz * ax_ - ux * az_, ux * ay_ - uy * ax_
            nn = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
            e1x, e1y, e1z = e1x / nn, e1y / nn, e1z / nn
            e2x, e2y, e2z = uy * e1z - uz * e1y, uz * e1x - ux * e1z, ux * e1y - uy * e1x
            for m in range(M):
                ca, sa = cos_m[m] * rho, sin_m[m] * rho
                wx = ox + ca * e1x + sa * e2x
                wy = oy + ca * e1y + sa * e2y
                wz = oz + ca * e1z + sa * e2z
                s = (Lz - zb) / (Lz - wz)
                px[n] = ((Lx + s * (wx - Lx)) + half) * scale
                py[n] = (half - (Ly + s * (wy - Ly))) * scale
                n += 1
        k = _convex_hull(px, py, n, hx, hy)
        _fill_convex(img, hx, hy, k, ur, vr)


def _render_batch(theta, parent, T_origin, axis, piece_link, piece_pts, piece_n, piece_r, light, zb, half, res, M):
    """``theta (B, J)`` → shadows ``(B, res, res)`` uint8 (1 = shadow). Window side ``2*half`` metres."""
    B, J = theta.shape
    out = np.zeros((B, res, res), dtype=np.uint8)
    scale = res / (2.0 * half)
    maxpts = piece_pts.shape[1] * M
    for b in prange(B):
        T = np.empty((J + 1, 4, 4))
        _fk_one(theta[b], parent, T_origin, axis, T)
        px = np.empty(maxpts)
        py = np.empty(maxpts)
        hx = np.empty(maxpts + 1)
        hy = np.empty(maxpts + 1)
        ur = np.empty(res)
        vr = np.empty(res)
        _render_one(
            T, piece_link, piece_pts, piece_n, piece_r, light, zb, half, scale, M, out[b], px, py, hx, hy, ur, vr
        )
    return out


# The same kernel compiled twice: threads over the batch for large batches, and serial for small ones, where
# waking the thread pool costs more than the work (refinement renders 8 shadows per step).
render_batch = njit(cache=True, parallel=True)(_render_batch)
render_batch_serial = njit(cache=True)(_render_batch)
SERIAL_BELOW = 64  # batches smaller than this use the serial kernel


def _fk_batch(theta, parent, T_origin, axis):
    """``theta (B, J)`` → ``T_world_link (B, J+1, 4, 4)`` (the compiled twin of ``kinematics.fk_numpy``)."""
    B, J = theta.shape
    out = np.empty((B, J + 1, 4, 4))
    for b in prange(B):
        _fk_one(theta[b], parent, T_origin, axis, out[b])
    return out


fk_batch = njit(cache=True, parallel=True)(_fk_batch)
fk_batch_serial = njit(cache=True)(_fk_batch)
