"""Bundle adjustment: sparse Levenberg-Marquardt over camera poses and points, with the Schur complement.

The unknowns are ``C`` camera poses ``T_wc`` (6 degrees of freedom each, perturbed
as ``T (+) delta = (R Exp(phi), t + R rho)``, :mod:`slamlib.camera`) and ``P``
world points (3 each). Each observation ``k`` of point ``p_k`` in camera ``c_k``
contributes the reprojection error ``e_k = project(K_c, T_c, P_p) - uv_k`` and its
Jacobians ``A_k = d e_k / d delta_c`` (2 x 6), ``B_k = d e_k / d P_p`` (2 x 3).
The normal equations ``H dx = -b`` have the arrow shape

    H = [[H_cc, H_cp], [H_pc, H_pp]],   H_pp block-diagonal in 3 x 3,

because an observation links one camera to one point. Eliminating the points
(:func:`schur_complement`) leaves the *reduced camera system*
``S dx_c = -s`` of size ``6C``; the points follow by back-substitution
(:func:`back_substitute`), one 3 x 3 solve each. With hundreds of points per
camera this is far cheaper than factorising ``H``.

:func:`bundle_adjust` runs Levenberg-Marquardt with the loop, damping and robust
kernels of :mod:`slamlib.graph_slam` (the same ``_optimize`` and sparse
``_Layout``), with the linear solve done by the Schur complement
(``linear_solver="schur"``), by a sparse factorisation of the whole ``H``
(``"sparse"``) or by a dense one (``"dense"``). The gauge
(a rigid motion and a scale leave every reprojection unchanged) is fixed by holding
the first camera and, with ``fix_scale=True``, one translation coordinate of the
second.

References
----------
B. Triggs, P. McLauchlan, R. Hartley, A. Fitzgibbon, "Bundle adjustment - a modern
synthesis", Vision Algorithms 1999, Sec. 6.1 (the Schur complement / reduced camera
system), Sec. 9 (gauge freedom); Hartley & Zisserman (2004), Appendix A6.3
(sparse Levenberg-Marquardt); S. Agarwal et al., "Bundle adjustment in the large",
ECCV 2010.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from ._checks import as_array, as_count, as_index_set, as_indices, as_scalar, check_choice
from .lie import _skew, _so3_exp
from .camera import _project
from .graph_slam import _kernel, _Layout, _optimize, _robust_args

__all__ = ["schur_complement", "back_substitute", "BAResult", "bundle_adjust", "reprojection_errors"]


# =========================================================================== the Schur complement
def _pp_blocks(H_pp):
    """The ``(P, 3, 3)`` diagonal blocks of a block-diagonal ``H_pp (3P, 3P)``."""
    idx = 3 * np.arange(H_pp.shape[0] // 3)[:, None] + np.arange(3)
    return H_pp[idx[:, :, None], idx[:, None, :]]


def _schur(H_cc, H_cp, Hpp_inv, b_c, b_p):
    """``(S, s)`` from dense blocks, ``Hpp_inv (P, 3, 3)`` the inverted point blocks."""
    W = np.einsum("apk,pkl->apl", H_cp.reshape(H_cp.shape[0], -1, 3), Hpp_inv).reshape(H_cp.shape)  # H_cp H_pp^-1
    # S = H_cc - H_cp H_pp^-1 H_pc, s = b_c - H_cp H_pp^-1 b_p  (Triggs et al. 1999, Eq. 28)
    return H_cc - W @ H_cp.T, b_c - W @ b_p


def _split(H, b, m):
    return H[:m, :m], H[:m, m:], H[m:, m:], b[:m], b[m:]


def schur_complement(H, b, n_cameras):
    """Eliminate the points from the bundle-adjustment normal equations ``H dx = -b``.

    Parameters
    ----------
    H : ndarray, shape (6C + 3P, 6C + 3P)
        Symmetric positive definite; the ``6C`` camera unknowns come first, then
        the points, and the point block ``H_pp`` is block-diagonal in ``3 x 3``.
    b : ndarray, shape (6C + 3P,)
    n_cameras : int
        ``C``.

    Returns
    -------
    S : ndarray, shape (6C, 6C)
        ``H_cc - H_cp H_pp^-1 H_pc``, the reduced camera system.
    s : ndarray, shape (6C,)
        ``b_c - H_cp H_pp^-1 b_p``; ``S dx_c = -s`` gives the cameras' step.

    References
    ----------
    Triggs et al. (1999), Sec. 6.1; Hartley & Zisserman (2004), Algorithm A6.4.
    """
    H, b, m = _as_system(H, b, n_cameras)
    H_cc, H_cp, H_pp, b_c, b_p = _split(H, b, m)
    return _schur(H_cc, H_cp, np.linalg.inv(_pp_blocks(H_pp)), b_c, b_p)  # H_pp^-1 block by block


def _back(H_pc, Hpp_inv, b_p, dx_c):
    r = (b_p + H_pc @ dx_c).reshape(-1, 3)
    return -np.einsum("pkl,pl->pk", Hpp_inv, r).ravel()  # dx_p = -H_pp^-1 (b_p + H_pc dx_c)


def back_substitute(H, b, n_cameras, dx_cameras):
    """The points' step ``dx_p = -H_pp^-1 (b_p + H_pc dx_c)`` once the cameras' step is known.

    Parameters
    ----------
    H, b, n_cameras
        As in :func:`schur_complement`.
    dx_cameras : ndarray, shape (6C,)
        Solution of ``S dx_c = -s``.

    Returns
    -------
    ndarray, shape (3P,)
        ``[dx_cameras, dx_points]`` solves ``H dx = -b``.

    References
    ----------
    Triggs et al. (1999), Sec. 6.1 (back-substitution); Hartley & Zisserman (2004), Algorithm A6.4.
    """
    H, b, m = _as_system(H, b, n_cameras)
    dx_c = as_array(dx_cameras, "dx_cameras", (m,))
    _, _, H_pp, _, b_p = _split(H, b, m)
    return _back(H[m:, :m], np.linalg.inv(_pp_blocks(H_pp)), b_p, dx_c)


def _as_system(H, b, n_cameras):
    H = as_array(H, "H", ndim=2)
    n = H.shape[0]
    if H.shape != (n, n):
        raise ValueError(f"H must be square, got shape {H.shape}")
    b = as_array(b, "b", (n,), ref="H")
    C = as_count(n_cameras, "n_cameras")
    m = 6 * C
    if m > n or (n - m) % 3:
        raise ValueError(f"H of size {n} does not hold 6 n_cameras = {m} camera unknowns followed by 3 per point")
    return H, b, m


# =========================================================================== the optimiser
class _SchurLayout:
    """The normal equations of bundle adjustment kept in blocks, solved by the Schur complement.

    Plays the part of :class:`slamlib.graph_slam._Layout` for ``_optimize``: ``data``
    holds the dense camera block ``H_cc`` of the free camera unknowns (``m x m``)
    followed by the ``3 x 3`` point blocks ``H_pp``; the camera-point blocks
    ``H_cp = sum_k A_k^T W_k B_k`` (6 x 3) stay one per camera and point seen by it,
    so the reduced camera system is summed over the pairs of cameras that see each
    point, ``S = H_cc - sum_j sum_{c, c' see j} H_cj H_pp,j^-1 H_c'j^T``, with no
    sparse matrix at all. With ``hooks = (schur_complement, back_substitute)`` (the
    contract functions, e.g. a student's), the dense ``H`` and ``b`` are handed to
    them instead.
    """

    def __init__(self, n_cam, n_pt, fixed_vars, cam, point, hooks=None):
        C = n_cam
        self.C, self.P, self.cam, self.point, self.hooks = C, n_pt, cam, point, hooks
        free = np.ones(6 * C, dtype=bool)
        free[list(fixed_vars)] = False
        self.idx = np.flatnonzero(free)  # free camera variables, in order
        m = self.m = self.idx.size
        self.n = m + 3 * n_pt
        self.diag = np.concatenate([np.arange(m) * (m + 1), m * m + 9 * np.arange(n_pt)[:, None] + [0, 4, 8]], axis=None)
        self.cc_idx = ((6 * cam[:, None, None] + np.arange(6)[:, None]) * (6 * C)
                       + 6 * cam[:, None, None] + np.arange(6)).ravel()
        self.bc_idx = (6 * cam[:, None] + np.arange(6)).ravel()
        self.pp_idx = (9 * point[:, None] + np.arange(9)).ravel()
        self.bp_idx = (3 * point[:, None] + np.arange(3)).ravel()
        # observations of the same camera and point share one H_cp block
        pairs, self.obs_pair = np.unique(cam * n_pt + point, return_inverse=True)
        self.U = pairs.size
        self.pair_cam, self.pair_point = pairs // n_pt, pairs % n_pt
        self.cp_idx = (18 * self.obs_pair[:, None] + np.arange(18)).ravel()
        # pairs (k, l) of camera-point blocks of the same point, both orders and k = l
        order = np.argsort(self.pair_point, kind="stable")
        counts = np.bincount(self.pair_point, minlength=n_pt)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        ks, ls = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
        for c in np.unique(counts[counts > 0]):
            members = order[starts[counts == c][:, None] + np.arange(c)]  # (points seen by c cameras, c)
            ks.append(np.repeat(members, c, axis=1).ravel())
            ls.append(np.tile(members, (1, c)).ravel())
        self.pk, self.pl = np.concatenate(ks), np.concatenate(ls)
        # the pairs sorted by the camera block (c_k, c_l) they add to, for one reduceat per step
        blk = self.pair_cam[self.pk] * C + self.pair_cam[self.pl]
        self.s_order = np.argsort(blk, kind="stable")
        self.s_blocks, self.s_starts = np.unique(blk[self.s_order], return_index=True)
        self.sc_idx = (6 * self.pair_cam[:, None] + np.arange(6)).ravel()
        self.pb_idx = (3 * self.pair_point[:, None] + np.arange(3)).ravel()

    def values(self, blocks):
        """``data = [H_cc (free), H_pp blocks]`` and ``b`` (free cameras, then points) from ``[(A, B, e, W)]``."""
        A, B, e, W = blocks[0]
        C, P = self.C, self.P
        At = np.swapaxes(A, 1, 2)
        WB, We = W @ B, np.einsum("kij,kj->ki", W, e)
        # H = sum J^T W J, b = sum J^T W e, block by block  (Triggs et al. 1999, Sec. 6.1)
        self.Hcp = np.bincount(self.cp_idx, (At @ WB).ravel(), minlength=18 * self.U).reshape(-1, 6, 3)
        Hcc = np.bincount(self.cc_idx, (At @ (W @ A)).ravel(), minlength=36 * C * C).reshape(6 * C, 6 * C)
        Hpp = np.bincount(self.pp_idx, (np.swapaxes(B, 1, 2) @ WB).ravel(), minlength=9 * P)
        b_c = np.bincount(self.bc_idx, np.einsum("kij,ki->kj", A, We).ravel(), minlength=6 * C)
        b_p = np.bincount(self.bp_idx, np.einsum("kij,ki->kj", B, We).ravel(), minlength=3 * P)
        data = np.concatenate([Hcc[np.ix_(self.idx, self.idx)].ravel(), Hpp])
        return data, np.concatenate([b_c[self.idx], b_p])

    def expand(self, dx):
        out = np.zeros(6 * self.C + 3 * self.P)
        out[self.idx] = dx[: self.m]
        out[6 * self.C:] = dx[self.m:]
        return out

    def _dense(self, data):
        """The whole ``H`` (free cameras, then points) as a dense array (for the hooks)."""
        m, C = self.m, self.C
        H = np.zeros((self.n, self.n))
        H[:m, :m] = data[: m * m].reshape(m, m)
        Hpp = data[m * m:].reshape(-1, 3, 3)
        v = m + 3 * np.arange(self.P)[:, None] + np.arange(3)
        H[v[:, :, None], v[:, None, :]] = Hpp
        Hcp = np.zeros((6 * C, 3 * self.P))
        np.add.at(Hcp, (6 * self.pair_cam[:, None, None] + np.arange(6)[:, None],
                        3 * self.pair_point[:, None, None] + np.arange(3)), self.Hcp)
        H[:m, m:] = Hcp[self.idx]
        H[m:, :m] = H[:m, m:].T
        return H

    def solve(self, data, rhs):
        m, C = self.m, self.C
        if self.hooks is not None:
            schur, back = self.hooks
            Hd, b = self._dense(data), -rhs
            S, s = schur(Hd, b, m // 6)
            dx_c = cho_solve(cho_factor(np.asarray(S, dtype=float)), -np.asarray(s, dtype=float))
            return np.concatenate([dx_c, np.asarray(back(Hd, b, m // 6, dx_c), dtype=float)])
        Hpp_inv = np.linalg.inv(data[m * m:].reshape(-1, 3, 3))
        b_p = -rhs[m:].reshape(-1, 3)
        Y = self.Hcp @ Hpp_inv[self.pair_point]  # H_cp H_pp^-1 per camera-point block, (U, 6, 3)
        # S = H_cc - H_cp H_pp^-1 H_pc over pairs of blocks of one point  (Triggs et al. 1999, Eq. 28)
        Z = np.add.reduceat(Y[self.pk[self.s_order]] @ np.swapaxes(self.Hcp[self.pl[self.s_order]], 1, 2),
                            self.s_starts, axis=0)  # one 6 x 6 block per pair of cameras sharing points
        full = np.zeros((C, C, 6, 6))
        full.reshape(C * C, 6, 6)[self.s_blocks] = Z
        full = full.transpose(0, 2, 1, 3).reshape(6 * C, 6 * C)
        sub = np.bincount(self.sc_idx, np.einsum("kij,kj->ki", Y, b_p[self.pair_point]).ravel(), minlength=6 * C)
        S = data[: m * m].reshape(m, m) - full[np.ix_(self.idx, self.idx)]
        s = -rhs[:m] - sub[self.idx]  # s = b_c - H_cp H_pp^-1 b_p
        dx_c = cho_solve(cho_factor(S), -s)  # S dx_c = -s
        dx_all = np.zeros(6 * C)
        dx_all[self.idx] = dx_c
        # dx_p = -H_pp^-1 (b_p + H_pc dx_c), H_pc dx_c summed over each point's blocks
        hpc_dx = np.bincount(self.pb_idx, np.einsum("kij,ki->kj", self.Hcp, dx_all.reshape(C, 6)[self.pair_cam]).ravel(),
                             minlength=3 * self.P).reshape(-1, 3)
        dx_p = -np.einsum("pkl,pl->pk", Hpp_inv, b_p + hpc_dx)
        return np.concatenate([dx_c, dx_p.ravel()])


class _DenseLayout(_Layout):
    """The pattern of ``H``; solves by a dense Cholesky factorisation of the whole ``H`` (no structure used)."""

    def solve(self, data, rhs):
        return cho_solve(cho_factor(self.matrix(data).toarray()), rhs)


class BAResult(NamedTuple):
    """Result of :func:`bundle_adjust`.

    Attributes
    ----------
    T_wc : ndarray, shape (C, 4, 4)
    points : ndarray, shape (P, 3)
    cost : ndarray, shape (iterations + 1,)
        ``sum_k rho(|e_k|^2)`` (pixels squared; ``rho(s) = s`` without a robust kernel) after each iteration.
    iterations : int
    converged : bool
    weights : ndarray, shape (O,)
        The robust kernel's weights of the observations at the end (ones without one).
    """

    T_wc: np.ndarray
    points: np.ndarray
    cost: np.ndarray
    iterations: int
    converged: bool
    weights: np.ndarray


def _project_offset(K, R, t, P, o):
    """Pixels and Jacobians of a sensor displaced by ``o`` (camera frame, no rotation) from the camera.

    ``q = R^T (P - t) - o`` is projected; a perturbation ``delta`` of the camera moves
    ``q`` by ``-rho + [p_c]x phi`` (``p_c = q + o``), so ``J_pose = D(q) [-I, [p_c]x]``.
    """
    pc = np.einsum("...ji,...j->...i", R, P - t)
    q = pc - o
    X, Y, iz = q[:, 0], q[:, 1], 1.0 / q[:, 2]
    fx, fy = K[..., 0, 0], K[..., 1, 1]
    uv = np.column_stack([fx * X * iz + K[..., 0, 2], fy * Y * iz + K[..., 1, 2]])
    zero = np.zeros_like(iz)
    D = np.stack([np.stack([fx * iz, zero, -fx * X * iz * iz], -1), np.stack([zero, fy * iz, -fy * Y * iz * iz], -1)], -2)
    return uv, np.concatenate([-D, D @ _skew(pc)], axis=-1), D @ np.swapaxes(R, -1, -2)


def _residuals(K, T, points, cam, point, uv, project=None, offset=None):
    """``(e (O, 2), A (O, 2, 6), B (O, 2, 3))`` of every observation (``project``: a hook per camera)."""
    if offset is not None:
        Kc = K[cam] if K.ndim == 3 else K
        uv_hat, A, B = _project_offset(Kc, T[cam, :3, :3], T[cam, :3, 3], points[point], offset)
        return uv_hat - uv, A, B
    if project is None:
        Kc = K[cam] if K.ndim == 3 else K
        uv_hat, A, B, _ = _project(Kc, T[cam, :3, :3], T[cam, :3, 3], points[point])
        return uv_hat - uv, A, B
    e, A, B = np.empty((len(cam), 2)), np.empty((len(cam), 2, 6)), np.empty((len(cam), 2, 3))
    for c in np.unique(cam):
        sel = np.flatnonzero(cam == c)
        u, a, bb = project(K[c] if K.ndim == 3 else K, T[c], points[point[sel]])
        e[sel], A[sel], B[sel] = np.asarray(u) - uv[sel], a, bb
    return e, A, B


def reprojection_errors(K, T_wc, points, cam, point, uv):
    """Reprojection errors of every observation.

    Parameters
    ----------
    K, T_wc, points, cam, point, uv
        As in :func:`bundle_adjust`.

    Returns
    -------
    ndarray, shape (O, 2)
        ``project(K_c, T_c, P_p) - uv_k`` in pixels.
    """
    K, T, points, cam, point, uv = _as_problem(K, T_wc, points, cam, point, uv)
    return _residuals(K, T, points, cam, point, uv)[0]


def _as_problem(K, T_wc, points, cam, point, uv):
    T = as_array(T_wc, "T_wc", (None, 4, 4))
    C = T.shape[0]
    K = as_array(K, "K", ndim=(2, 3))
    if K.shape not in ((3, 3), (C, 3, 3)):
        raise ValueError(f"K must have shape (3, 3) or ({C}, 3, 3) (to match T_wc), got {K.shape}")
    points = as_array(points, "points", (None, 3))
    cam = as_indices(cam, "cam", C)
    point = as_indices(point, "point", points.shape[0])
    if cam.ndim != 1 or point.ndim != 1:
        raise ValueError(f"cam and point must be 1-D index arrays, got shapes {cam.shape} and {point.shape}")
    uv = as_array(uv, "uv", (None, 2))
    if not (len(cam) == len(point) == len(uv)):
        raise ValueError(f"cam, point and uv must have one row per observation, got {len(cam)}, {len(point)}, "
                         f"{len(uv)}")
    return K, T, points, cam, point, uv


def _update(state, dx, C, exp):
    T, points = state
    d = dx[:6 * C].reshape(C, 6)
    R = T[:, :3, :3]
    Tn = T.copy()
    Tn[:, :3, :3] = R @ (exp(d[:, 3:]) if exp is _so3_exp else np.stack([exp(v) for v in d[:, 3:]]))
    Tn[:, :3, 3] = T[:, :3, 3] + np.einsum("cij,cj->ci", R, d[:, :3])  # T (+) delta = (R Exp(phi), t + R rho)
    return Tn, points + dx[6 * C:].reshape(-1, 3)


def bundle_adjust(T_wc, points, K, cam, point, uv, *, fixed=(0,), fix_scale=False, robust=None, robust_scale=None,
                  linear_solver="schur", method="lm", max_iter=50, rtol=1e-10, lm_lambda=1e-7, offset=None,
                  project=None, so3_exp=None, schur_complement=None, back_substitute=None):
    """Bundle adjustment by Levenberg-Marquardt (or Gauss-Newton) over camera poses and points.

    Parameters
    ----------
    T_wc : ndarray, shape (C, 4, 4)
        Initial camera poses (camera-to-world).
    points : ndarray, shape (P, 3)
        Initial world points.
    K : ndarray, shape (3, 3) or (C, 3, 3)
        Calibration, shared or per camera (held fixed).
    cam, point : ndarray of int, shape (O,)
        Camera and point of each observation.
    uv : ndarray, shape (O, 2)
        Observed pixels.
    fixed : sequence of int, keyword-only
        Cameras held fixed (the gauge: default the first).
    fix_scale : bool, keyword-only
        Also hold the translation coordinate of camera ``fixed[0] + 1``'s step
        ``rho`` along which it lies farthest from camera ``fixed[0]`` (the scale
        gauge); without it the damping of LM keeps the step finite.
    robust : {"huber", "cauchy"} or None, keyword-only
        Robust kernel on the squared reprojection error (IRLS, as in
        :func:`slamlib.optimize_pose_graph`); `robust_scale` its width in pixels
        (default ``sqrt(chi2_2(0.95)) = 2.45``).
    linear_solver : {"schur", "sparse", "dense"}, keyword-only
        How each step's normal equations are solved: by the Schur complement (the
        reduced camera system, then back-substitution), by a sparse factorisation
        of the whole ``H`` (fill-reducing order, as :func:`slamlib.optimize_pose_graph`),
        or by a dense Cholesky factorisation of the whole ``H`` (the textbook
        Levenberg-Marquardt that ignores the structure). All three give the same
        steps up to rounding.
    method : {"lm", "gn"}, keyword-only
    max_iter, rtol, lm_lambda : keyword-only
        Iteration limit, relative cost change that stops, and LM's initial damping
        relative to the mean of ``diag H`` (:func:`slamlib.optimize_pose_graph`).
    offset : ndarray, shape (O, 3), optional, keyword-only
        Position, in its camera's frame, of the sensor that made each observation
        (no rotation): ``[b, 0, 0]`` for the right image of a rectified stereo pair of
        baseline ``b``, zeros for the left (the camera itself). A stereo rig is then one
        pose per frame.
    project, so3_exp, schur_complement, back_substitute : callable, keyword-only
        Hooks replacing the library's own :func:`slamlib.project` (called once per
        camera), :func:`slamlib.so3_exp` (in the pose update, once per camera),
        and the Schur elimination (both together; the dense ``H`` of the free
        cameras and all points is passed, with ``fixed`` and no ``fix_scale``).

    Returns
    -------
    BAResult

    References
    ----------
    Triggs et al. (1999); Hartley & Zisserman (2004), Sec. A6.3; Madsen, Nielsen &
    Tingleff, *Methods for non-linear least squares problems* (2004) (the damping).
    """
    K, T, P, cam, point, uv = _as_problem(K, T_wc, points, cam, point, uv)
    C, n_pt = T.shape[0], P.shape[0]
    if offset is not None:
        offset = as_array(offset, "offset", (len(cam), 3), ref="cam")
        if project is not None:
            raise ValueError("offset and a project hook cannot be combined")
    fixed = list(as_index_set(fixed, "fixed", C, what="camera index")) if len(fixed) else []
    check_choice(method, "method", {"gn": "Gauss-Newton", "lm": "Levenberg-Marquardt"})
    max_iter = as_count(max_iter, "max_iter")
    rtol = as_scalar(rtol, "rtol", nonnegative=True)
    robust, k = _robust_args(robust, robust_scale, 2)
    check_choice(linear_solver, "linear_solver", {"schur": "Schur complement", "sparse": "sparse factorisation",
                                                  "dense": "dense Cholesky factorisation"})
    hooks = None
    if (schur_complement is None) != (back_substitute is None):
        raise ValueError("schur_complement and back_substitute are plugged in together")
    if schur_complement is not None:
        if fix_scale or linear_solver != "schur":
            raise ValueError("schur_complement and back_substitute need linear_solver='schur' and fix_scale=False")
        hooks = (schur_complement, back_substitute)
    fixed_vars = [6 * c + i for c in fixed for i in range(6)]
    if fix_scale:
        if not fixed or C < 2:
            raise ValueError("fix_scale needs a fixed camera and a second one")
        c0 = fixed[0]
        c1 = (c0 + 1) % C
        base = T[c1, :3, :3].T @ (T[c1, :3, 3] - T[c0, :3, 3])
        fixed_vars.append(6 * c1 + int(np.argmax(np.abs(base))))
    m = 6 * C - len(fixed_vars)
    terms = [(6 * cam, 6, 6 * C + 3 * point, 3)]
    n_var = 6 * C + 3 * n_pt
    if linear_solver == "schur":
        layout = _SchurLayout(C, n_pt, fixed_vars, cam, point, hooks)
    elif linear_solver == "sparse":
        layout = _Layout(n_var, terms, fixed_vars, order=True)
    else:
        layout = _DenseLayout(n_var, terms, fixed_vars, order=False)
    eye = np.eye(2)
    exp = _so3_exp if so3_exp is None else so3_exp

    def evaluate(state):
        e, A, B = _residuals(K, state[0], state[1], cam, point, uv, project, offset)
        s = np.einsum("ki,ki->k", e, e)
        cost, w = _kernel(s, robust, k)
        return float(cost.sum()), float(s.sum()), [(A, B, e, w[:, None, None] * eye)], w

    (T_out, P_out), _, costs, it, conv, w = _optimize(
        (T, P), evaluate, layout, lambda st, dx: _update(st, dx, C, exp), method=method, max_iter=max_iter,
        rtol=rtol, lm_lambda=lm_lambda)
    return BAResult(T_out, P_out, costs, it, conv, w)
