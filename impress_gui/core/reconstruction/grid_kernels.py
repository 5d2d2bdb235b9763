"""Compiled kernels of the grid (numba): the texture mapping onto the surface, the per-cell
means, the fusion of the two lasers' maps, and the undistortion behind the per-run ray tables.
Reached through :mod:`impress_gui.core.reconstruction.kernels` (which re-exports them), with its rules: one
explicit signature each, GIL released, deterministic order of accumulation.
"""

from __future__ import annotations

import math

import numpy as np

from impress_gui.core.reconstruction.jit import helper as _jit
from impress_gui.core.reconstruction.jit import kernel as _kernel

#: a texture ray's hit on the surface is final once refining it moves it less than this
HIT_TOLERANCE_MM = 1e-3


@_jit
def _height(img, i, j):
    """A cell of the heightmap; a missing one (NaN) at the reference, 0."""
    v = img[i, j]
    return 0.0 if math.isnan(v) else v


@_jit
def _bilinear_clamped(img, fx, fy):
    """The heightmap at fractional cell ``(fy, fx)``: bilinear, clamped at its border,
    missing cells at 0."""
    hh, ww = img.shape
    fx = min(max(fx, 0.0), ww - 1.0)
    fy = min(max(fy, 0.0), hh - 1.0)
    j = min(int(fx), ww - 2) if ww > 1 else 0
    i = min(int(fy), hh - 2) if hh > 1 else 0
    a = fx - j
    b = fy - i
    j1 = min(j + 1, ww - 1)
    i1 = min(i + 1, hh - 1)
    top = _height(img, i, j) * (1 - a) + _height(img, i, j1) * a
    bot = _height(img, i1, j) * (1 - a) + _height(img, i1, j1) * a
    return top * (1 - b) + bot * b


@_jit
def surface_hits(ax, ay, travel, ref, height, x0, y0, g, iterations, x_out, y_out):
    """Where the texture row's rays meet the reconstructed surface: the ray through
    ``(ax, ay, 1)`` from the camera at ``travel``, depth refined on the heightmap (bilinear,
    clamped at its border; missing cells at the reference) at most ``iterations``
    times, and no more once an iteration moves it by less than :data:`HIT_TOLERANCE_MM`
    (further iterations would not move the hit)."""
    ig = 1.0 / g
    for i in range(ax.shape[0]):
        z = ref[0] + ref[2] * travel
        for _ in range(iterations):
            x = ax[i] * z
            y = travel + ay[i] * z
            hv = _bilinear_clamped(height, (x - x0) * ig, (y - y0) * ig)
            zn = ref[0] + ref[1] * x + ref[2] * y - hv
            moved = abs(zn - z)
            z = zn
            if moved < HIT_TOLERANCE_MM:
                break
        x_out[i] = ax[i] * z
        y_out[i] = travel + ay[i] * z


@_jit
def splat_colours(total, count, hgt, mask, x0, y0, g, x, y, rgb, px, py, prgb, has_prev,
                  max_gap, i_lo, i_hi):
    """Add one texture row's colours (``(N, 3)``) to the per-cell sums, filling the strip
    towards the previous row (linear colours): at most one cell apart along each axis, so
    the strip has no gaps (a texture is a picture: fewer samples than the heights need). Only
    grid rows ``i_lo <= i < i_hi`` are touched; returns how many samples fell on other rows of
    the grid (threads sharing the grid by row ranges use it to check their split). The grid
    has ``hgt`` rows; grid row ``i`` is stored in row ``i & mask`` of the sums (``mask`` -1:
    the sums cover the whole grid; ``2**k - 1``: a ring of ``2**k`` rows, which must hold
    every row from ``i_lo`` to ``i_hi - 1``)."""
    wid = count.shape[1]
    ig = 1.0 / g
    skipped = 0
    for i in range(x.shape[0]):
        if math.isnan(x[i]) or math.isnan(y[i]):
            continue
        n = 1
        dx = 0.0
        dy = 0.0
        if has_prev and not (math.isnan(px[i]) or math.isnan(py[i])):
            dx = x[i] - px[i]
            dy = y[i] - py[i]
            if math.hypot(dx, dy) <= max_gap:
                n = max(1, int(math.ceil(max(abs(dx), abs(dy)) * ig)))
        # in cells: this row's point and the step back towards the previous row's
        fx, fy = (x[i] - x0) * ig, (y[i] - y0) * ig
        sx, sy = dx * ig / n, dy * ig / n
        for m in range(n):  # m = 0 is this row's own point; the others fill towards the previous
            jj = int(np.rint(fx - m * sx))
            ii = int(np.rint(fy - m * sy))
            if not (0 <= ii < hgt and 0 <= jj < wid):
                continue
            if not (i_lo <= ii < i_hi):
                skipped += 1
                continue
            ri = ii & mask
            if count[ri, jj] < 65535:
                t = m / n
                for q in range(3):
                    c = rgb[i, q]
                    total[ri, jj, q] += c if m == 0 else c - t * (c - prgb[i, q])
                count[ri, jj] += 1
    return skipped


@_kernel(
    "int64(float64[:], float64[:], float64[:], float64[:], float32[:, :], float64, float64, float64, uint8[:, :, :], float32[:, :, :], uint16[:, :], int64, float64, float64[:], float64[:], float64[:, :], boolean[:], int64, int64)"
)
def texture_rows(ax, ay, travels, ref, height, x0, y0, g, colours, total, count, mask, max_gap,
                 prev_x, prev_y, prev_rgb, has_prev, i_lo, i_hi):
    """Map a run of texture rows (``colours`` ``(n, N, 3)`` uint8, camera travel of each in
    ``travels``) onto grid rows ``i_lo .. i_hi - 1``: :func:`surface_hits` then
    :func:`splat_colours` per row (the sums cover the grid of ``height``, or a ring of its rows:
    ``mask``). The previous row's state (``prev_*``; ``has_prev[0]``) is carried in and out.
    Returns the number of samples that fell on other grid rows."""
    n_pts = ax.shape[0]
    x = np.empty(n_pts)
    y = np.empty(n_pts)
    rgb = np.empty((n_pts, 3))
    skipped = 0
    for r in range(travels.shape[0]):
        surface_hits(ax, ay, travels[r], ref, height, x0, y0, g, 4, x, y)
        for i in range(n_pts):
            for q in range(3):
                rgb[i, q] = colours[r, i, q]
        skipped += splat_colours(total, count, height.shape[0], mask, x0, y0, g, x, y, rgb,
                                 prev_x, prev_y, prev_rgb, has_prev[0], max_gap, i_lo, i_hi)
        prev_x[:] = x
        prev_y[:] = y
        prev_rgb[:, :] = rgb
        has_prev[0] = True
    return skipped


@_kernel(
    "void(float32[:, :], uint16[:, :], float32[:, :])"
)
def mean_heights(total, count, out):
    """``out = total / count`` (float32), NaN where ``count == 0``."""
    for i in range(count.shape[0]):
        for j in range(count.shape[1]):
            n = count[i, j]
            out[i, j] = total[i, j] / n if n > 0 else np.nan


@_kernel(
    "void(float32[:, :, :], uint16[:, :], uint8[:, :, :])"
)
def mean_colours(total, count, out):
    """Rounded mean colour per cell (uint8), 0 where ``count == 0``."""
    for i in range(count.shape[0]):
        for j in range(count.shape[1]):
            n = max(count[i, j], 1)
            for q in range(3):
                out[i, j, q] = np.uint8(min(max(total[i, j, q] / n + 0.5, 0.0), 255.0))


@_jit
def _reflect(i, n):
    """scipy.ndimage's 'reflect' border: (d c b a | a b c d | d c b a)."""
    if i < 0:
        return -i - 1
    if i >= n:
        return 2 * n - i - 1
    return i


@_kernel(
    "int64(float32[:, :], float32[:, :], float64, float32[:, :], float32[:, :], uint8[:, :], int64, int64, float64)"
)
def fuse_rows(hg, hr, tol, fused, diff, contrib, lo, hi, wg):
    """First pass of the fusion (see ``grid.fuse`` for the codes) over rows ``lo .. hi - 1``:
    single lasers and agreeing pairs are fused (``wg``: the green laser's weight in an
    agreeing pair's mean); where both have data but disagree by more
    than ``tol`` the cell is marked 4 (NaN) for :func:`resolve_conflicts`. Returns how many."""
    conflicts = 0
    for i in range(lo, hi):
        for j in range(hg.shape[1]):
            g, r = hg[i, j], hr[i, j]
            g_ok, r_ok = not math.isnan(g), not math.isnan(r)
            diff[i, j] = g - r if (g_ok and r_ok) else np.nan
            if g_ok and r_ok:
                if abs(g - r) <= tol:
                    fused[i, j], contrib[i, j] = wg * g + (1.0 - wg) * r, 3
                else:
                    fused[i, j], contrib[i, j] = np.nan, 4
                    conflicts += 1
            elif g_ok:
                fused[i, j], contrib[i, j] = g, 1
            elif r_ok:
                fused[i, j], contrib[i, j] = r, 2
            else:
                fused[i, j], contrib[i, j] = np.nan, 0
    return conflicts


@_kernel(
    "void(float32[:, :], float32[:, :], int64, float32[:, :], uint8[:, :], int64, int64)"
)
def resolve_conflicts(hg, hr, radius, fused, contrib, lo, hi):
    """Second pass over rows ``lo .. hi - 1`` (the first must have covered ``radius`` rows
    more on each side): each disagreeing cell takes the laser's value nearer the local
    consensus, the mean of the cells fused from agreeing or single lasers (codes 1-3) in the
    ``(2 radius + 1)`` square around it (reflected at the grid's border). Conflict cells
    never count, decided or not, so the result does not depend on the order of the rows."""
    hh, ww = fused.shape
    for i in range(lo, hi):
        for j in range(ww):
            if contrib[i, j] != 4:
                continue
            s = 0.0
            n = 0.0
            for di in range(-radius, radius + 1):
                ii = _reflect(i + di, hh)
                for dj in range(-radius, radius + 1):
                    jj = _reflect(j + dj, ww)
                    c = contrib[ii, jj]
                    if c != 0 and c != 4:
                        s += fused[ii, jj]
                        n += 1.0
            local = s / n if n > 0 else 0.0
            g, r = hg[i, j], hr[i, j]
            fused[i, j] = g if abs(g - local) <= abs(r - local) else r


@_jit
def _undistort_point(xd, yd, x, y, coeffs, rational):
    """Normalized distorted coordinates -> undistorted (OpenCV's model, ``coeffs`` k1 k2 p1 p2
    k3 [k4 k5 k6]): fixed-point iteration from the guess ``(x, y)`` until it moves less than
    1e-13 (at most 100 times), as :meth:`impress_gui.core.calibration.geometry.Intrinsics.undistort_points`."""
    k1, k2, p1, p2, k3 = coeffs[0], coeffs[1], coeffs[2], coeffs[3], coeffs[4]
    for _ in range(100):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if rational:
            radial = radial / (1 + r2 * (coeffs[5] + r2 * (coeffs[6] + r2 * coeffs[7])))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        xn, yn = (xd - dx) / radial, (yd - dy) / radial
        delta = max(abs(xn - x), abs(yn - y))
        x, y = xn, yn
        if delta < 1e-13:
            break
    return x, y


@_kernel(
    "void(int64[:], int64, float64[:, :], float64[:], boolean, float64[:, :], float64[:, :, :])"
)
def band_rays(band_start, height, camera, coeffs, rational, rot, out):
    """Rail-frame ray directions ``out[c, j]`` through column ``c`` at image row
    ``min(band_start[c] + j, height - 1)``: the pixel undistorted (:func:`_undistort_point`,
    each point starting from the correction extrapolated from the two above it), then the camera ray
    ``(x, y, 1)`` turned by ``rot`` - ``Intrinsics.rays(uv) @ rot.T`` in one pass."""
    fx, skew, cx = camera[0, 0], camera[0, 1], camera[0, 2]
    fy, cy = camera[1, 1], camera[1, 2]
    for c in range(out.shape[0]):
        # each point starts from its neighbours' corrections, extrapolated along the column
        ax = ay = bx = by = 0.0  # the corrections of the two previous points
        for j in range(out.shape[1]):
            yd = (min(band_start[c] + j, height - 1) - cy) / fy
            xd = (c - cx - skew * yd) / fx
            if j >= 2:
                x, y = xd + 2 * ax - bx, yd + 2 * ay - by
            elif j == 1:
                x, y = xd + ax, yd + ay
            else:
                x, y = xd, yd
            x, y = _undistort_point(xd, yd, x, y, coeffs, rational)
            bx, by = ax, ay
            ax, ay = x - xd, y - yd
            for m in range(3):
                out[c, j, m] = rot[m, 0] * x + rot[m, 1] * y + rot[m, 2]
