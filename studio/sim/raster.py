"""Compiled kernels of the shadow renderer (numba): FK, exact point-light projection of convex pieces,
convex hull and scanline fill at pixel centres. Pure compute; ``studio.sim.shadow`` is the public face.

Per piece the outline points are put in (x, y) order by O(M) merges (each projected ring is already a convex
polygon in angular order), then Andrew's monotone chain gives the hull and a per-edge scanline fills it. The
sorted order is unique, so the pixels are exactly those of a plain sort + hull + fill; ``tests/test_shadow.py``
checks them bit for bit against a slow pure-Python twin.

A piece is the convex hull of ``n`` spheres of one radius ``r`` (capsule: 2 centres, sphere: 1, box: its 8
corners with r = 0). Its shadow is the convex hull of the shadows of those spheres; the shadow of a sphere under
a point light is the projection of the sphere's contact circle with its tangent cone from the light (an
ellipse on the backdrop), sampled at ``M`` points scaled to keep the ellipse's area.
"""

from __future__ import annotations

import math
import types

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


@njit(cache=True, inline="always")
def _cross(ox, oy, ax, ay, bx, by):
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@njit(cache=True, inline="always")
def _before(ax, ay, bx, by):
    """(ax, ay) < (bx, by) in (x, y) order."""
    return ax < bx or (ax == bx and ay < by)


@njit(cache=True, inline="always")
def _merge_ring(rx, ry, M, px, py, n, qx, qy):
    """Merge the ring ``(rx, ry)[:M]`` into the (x, y)-sorted ``(px, py)[:n]``, giving the sorted ``[:n + M]``.

    The ring is a convex polygon in angular order, stored twice over (``rx[M + m] == rx[m]``) so that index
    arithmetic needs no modulo: its two chains from the first to the last point in (x, y) order are each
    sorted, so one O(M) merge of the chains sorts it (into ``qx, qy``), and a second merges it into ``px, py``
    from the back, in place. Rounding can break a chain's order by an ulp near a vertical edge; the merges
    still output a permutation, and ``_sort_xy`` afterwards puts any such point back in its place."""
    a = 0
    b = 0
    for m in range(1, M):
        if _before(rx[m], ry[m], rx[a], ry[a]):
            a = m
        if _before(rx[b], ry[b], rx[m], ry[m]):
            b = m
    nf = b - a + 1 if b >= a else b - a + M + 1  # forward chain a, a+1, ..., b; backward a-1, a-2, ..., b+1
    nb = M - nf
    f = a  # next forward index
    g = a + M - 1  # next backward index
    ge = g - nb  # backward chain exhausted when g == ge
    fe = a + nf
    for t in range(M):
        fx, fy, gx, gy = rx[f], ry[f], rx[g], ry[g]
        take_g = g != ge and (f == fe or _before(gx, gy, fx, fy))
        if take_g:
            qx[t] = gx
            qy[t] = gy
            g -= 1
        else:
            qx[t] = fx
            qy[t] = fy
            f += 1
    i = n - 1
    j = M - 1
    k = n + M - 1
    while j >= 0:
        if i >= 0 and _before(qx[j], qy[j], px[i], py[i]):
            px[k] = px[i]
            py[k] = py[i]
            i -= 1
        else:
            px[k] = qx[j]
            py[k] = qy[j]
            j -= 1
        k -= 1


@njit(cache=True, inline="always")
def _sort_xy(px, py, n):
    """Insertion sort of ``(px, py)[:n]`` by (x, y) in place: O(n) on sorted input, O(n²) at worst (n <= 8 * M)."""
    for i in range(1, n):
        x, y = px[i], py[i]
        k = i - 1
        while k >= 0 and (px[k] > x or (px[k] == x and py[k] > y)):
            px[k + 1] = px[k]
            py[k + 1] = py[k]
            k -= 1
        px[k + 1] = x
        py[k + 1] = y


@njit(cache=True, inline="always")
def _hull_sorted(px, py, n, hx, hy):
    """Andrew's monotone chain on ``n`` points sorted by (x, y); writes the counter-clockwise hull (collinear
    and repeated points dropped) into hx, hy and returns its size."""
    # the top two stack points are kept in locals (x1, y1 = hx[k-1], hy[k-1]; x2, y2 = hx[k-2], hy[k-2])
    k = 0
    x1 = y1 = x2 = y2 = 0.0
    for i in range(n):  # lower hull
        x, y = px[i], py[i]
        while k >= 2 and _cross(x2, y2, x1, y1, x, y) <= 0:
            k -= 1
            x1, y1 = x2, y2
            if k >= 2:
                x2, y2 = hx[k - 2], hy[k - 2]
        hx[k] = x
        hy[k] = y
        k += 1
        x2, y2, x1, y1 = x1, y1, x, y
    t = k + 1
    for i in range(n - 2, -1, -1):  # upper hull
        x, y = px[i], py[i]
        while k >= t and _cross(x2, y2, x1, y1, x, y) <= 0:
            k -= 1
            x1, y1 = x2, y2
            x2, y2 = hx[k - 2], hy[k - 2]
        hx[k] = x
        hy[k] = y
        k += 1
        x2, y2, x1, y1 = x1, y1, x, y
    return k - 1 if k > 1 else k


@njit(cache=True, inline="always")
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
        e1 = e + 1 if e + 1 < k else 0
        bx, by = hx[e1], hy[e1]
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
        if j1 >= j0:
            img[i, j0 : j1 + 1] = 1


@njit(cache=True, inline="always")
def _ring_table(M):
    """Unit ring ``cos, sin (M,)`` and the radius factor that makes the M-gon keep its circle's area."""
    ring_k = math.sqrt(2 * math.pi / (M * math.sin(2 * math.pi / M)))
    cos_m = np.empty(M)
    sin_m = np.empty(M)
    for m in range(M):
        cos_m[m] = math.cos(2.0 * math.pi * m / M)
        sin_m[m] = math.sin(2.0 * math.pi * m / M)
    return cos_m, sin_m, ring_k


@njit(cache=True, inline="always")
def _render_one(T, piece_link, piece_pts, piece_n, piece_r, light, zb, half, scale, ring, img, buf):
    """Shadow of one posed hand (link poses ``T (L, 4, 4)``) into ``img (H, W)`` uint8 (already zero).

    ``ring`` is ``_ring_table(M)``; ``buf`` holds the scratch rows (points, ring, merge, hull, row spans)."""
    cos_m, sin_m, ring_k = ring
    M = cos_m.shape[0]
    px, py, rx, ry, qx, qy, hx, hy, ur, vr = buf
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
                rx[m] = rx[M + m] = ((Lx + s * (wx - Lx)) + half) * scale
                ry[m] = ry[M + m] = (half - (Ly + s * (wy - Ly))) * scale
            _merge_ring(rx, ry, M, px, py, n, qx, qy)
            n += M
        _sort_xy(px, py, n)  # boxes' corners; a no-op pass over merged rings
        k = _hull_sorted(px, py, n, hx, hy)
        _fill_convex(img, hx, hy, k, ur, vr)


CHUNK = 16  # poses per scratch allocation in the batch kernels


def _render_into(out, theta, parent, T_origin, axis, piece_link, piece_pts, piece_n, piece_r, light, zb, half, M):
    """``theta (B, J)`` → shadows written into ``out (B, res, res)`` uint8 (1 = shadow; any prior content is
    overwritten). Window side ``2*half`` metres; ``M`` points per projected sphere outline."""
    B, J = theta.shape
    res = out.shape[1]
    scale = res / (2.0 * half)
    ring = _ring_table(M)
    maxpts = piece_pts.shape[1] * M
    for c in prange((B + CHUNK - 1) // CHUNK):
        T = np.empty((J + 1, 4, 4))
        buf = (
            np.empty(maxpts), np.empty(maxpts), np.empty(2 * M), np.empty(2 * M), np.empty(M), np.empty(M),
            np.empty(maxpts + 1), np.empty(maxpts + 1), np.empty(res), np.empty(res),
        )  # fmt: skip
        for b in range(c * CHUNK, min(B, (c + 1) * CHUNK)):
            img = out[b]
            img[:, :] = 0
            _fk_one(theta[b], parent, T_origin, axis, T)
            _render_one(T, piece_link, piece_pts, piece_n, piece_r, light, zb, half, scale, ring, img, buf)
    return out


def serial_twin(fn):
    """A copy of ``fn`` under its own name, for its serial compilation. numba keys a function's on-disk cache by its
    module, name and first line, not by its options (numba issue #6845): a threaded and a serial ``njit`` of one
    function would both load whichever of the two was compiled first after an install, and either the large batches
    ran on one core (the retrieval index's build, the block sweep's draws) or the small ones woke the thread pool."""
    twin = types.FunctionType(fn.__code__, fn.__globals__, fn.__name__ + "_serial", fn.__defaults__, fn.__closure__)
    twin.__qualname__ = fn.__qualname__ + "_serial"
    return twin


# The same kernel compiled twice: threads over the batch for large batches, and serial for small ones, where
# waking the thread pool costs more than the work (refinement renders 8 shadows per step).
render_into = njit(cache=True, parallel=True, nogil=True)(_render_into)  # nogil: a UI thread runs meanwhile
render_into_serial = njit(cache=True, nogil=True)(serial_twin(_render_into))
SERIAL_BELOW = 64  # batches smaller than this use the serial kernel


def _fk_batch(theta, parent, T_origin, axis):
    """``theta (B, J)`` → ``T_world_link (B, J+1, 4, 4)`` (the compiled twin of ``kinematics.fk_numpy``)."""
    B, J = theta.shape
    out = np.empty((B, J + 1, 4, 4))
    for b in prange(B):
        _fk_one(theta[b], parent, T_origin, axis, out[b])
    return out


fk_batch = njit(cache=True, parallel=True, nogil=True)(_fk_batch)
fk_batch_serial = njit(cache=True, nogil=True)(serial_twin(_fk_batch))
