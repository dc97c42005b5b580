"""The per-step linear algebra of FPM's and CPM's forcing and control-rate filters, fused into a
few kernels, compiled with numba where it is installed (the ``fast`` extra) and plain numpy
where it is not: ONE code path, the same Python functions either way.

Each kernel is written in numpy's array operations, in the order and with the calls of the
functions it fuses (:func:`~tamedpuma.methods._policy.pull_to_joints`,
:func:`~tamedpuma.methods._policy.pull_through_metric`,
:func:`~tamedpuma.methods._tamed.restore_approached`, the free case of
:func:`~tamedpuma.fabrics.discrete.barrier_step`, ...). Run plain they are those numpy calls, bit
for bit; compiled, numba calls the same BLAS/LAPACK routines for the products and solves, but
its own loops and element-wise arithmetic may round differently in the last bit
(tests/test_step_kernels.py holds them to 1e-12 relative), and it removes the ~1-3 µs of Python
and numpy dispatch each of the ~60 small calls costs. On Table 1 (480 runs) the plain kernels
give every run of the code before the fusion to the bit; compiled, 478 are identical and two
FPM runs that go on for the whole 40 s (pouring 14 and 06) end 0.005 mm and 17 mm apart (the
same outcomes): a last-bit difference grows over 2000 steps of a hand that does not rest.

The kernels compile when a controller is built (:func:`warm_up`, from numba's on-disk cache
after the first time), never inside a step: after the warm-up the dispatchers compile nothing
more, and a kernel handed argument types the warm-up did not see runs as the plain function
(the same numbers) for the rest of the process (:class:`Kernel`). Without numba
(``AVAILABLE`` False), or where it fails to compile, every call is plain.

Kernels (n joints, m task rows, R barrier rows):

- :func:`damped_pull`: ``q̈ = J⁺ t + (I − J⁺J) q̈_null``, ``J⁺ = Jᵀ(JJᵀ + λ²I)⁻¹`` [rad/s²].
- :func:`metric_forcing`: ``q̈_C = (W + w JᵀJ + m_null I)⁻¹ (w Jᵀ t + m_null q̈_null)`` with W
  the avoidance metric M less the barrier rows q̈_P recedes from (``a_r·q̈_P > 0``, m_r > 0), the
  rows q̈_C approaches put back until none is (directional),
  and the geometry ``h = −(M + [task] w JᵀJ)⁻¹ f`` [rad/s²].
- :func:`pulled_forcing`: :func:`metric_forcing` with its q̈_P (:func:`damped_pull`) in one call.
- :func:`lowest_points`, :func:`ground_rows`: the links' lowest hull points and their ground
  rows (:func:`~tamedpuma.robot.ground.hull_ground_rows`); :func:`ground_reach`: how far the
  joints may move before any hull needs a row.
- :func:`rows_free`: whether v meets every barrier row ``a·v ≥ b`` (and ``a·v + drift ≥ b``),
  ``b = −κ(x − x_s)/Δt − ½Δt min(J̇q̇, 0)`` (``min(b, 0)`` on rows at or past x_s).
- :func:`null_pull`: the elbow objective ``q̈_null = k J_linkᵀ (p* − p_link) − d q̇`` [rad/s²]
  from the chain's joint state.
- :func:`fpm_velocity`, :func:`cpm_velocity`: FPM's and CPM's laws from the forced fabric to
  the velocity the control-rate filters take (energization α, CPM's regulator and damping, the
  semi-implicit step). Their products are ``np.dot`` on the arrays numpy's ``@`` takes, which
  numba hands to the same BLAS routines: compiled, they give the plain functions' numbers (on
  replayed FPM and CPM episodes, every command bit for bit).
- :func:`~tamedpuma.fabrics.discrete.limit_speed`: the uniform speed limit ``s v``,
  ``s = min(1, min_j q̇_lim,j/|v_j|)``.
"""

from __future__ import annotations

import importlib.util
import warnings

import numpy as np

from tamedpuma.fabrics.discrete import energized_velocity_step, limit_speed
from tamedpuma.robot.point_motion import frame_motion

#: numba is installed: the kernels are compiled (imported only by :func:`warm_up`)
AVAILABLE = importlib.util.find_spec("numba") is not None
_COMPILED: list = []  # [the compiled kernels by name, or None] once tried


def damped_pull(J, target, lam2, qdd_null, has_null):
    """``q̈ = J⁺ t + (I − J⁺J) q̈_null`` [rad/s²], ``J⁺ = Jᵀ(JJᵀ + λ²I)⁻¹`` (by a solve);
    J (m, n), t = ẍ_d − J̇q̇ (m,), lam2 = λ², q̈_null (n,) used when has_null."""
    G = J @ J.T
    for i in range(G.shape[0]):
        G[i, i] += lam2
    # C order first (numba's solve returns Fortran order): J⁺ is then the transpose of a C
    # array in both, and its products take the same BLAS route (the same numbers)
    pinv = np.ascontiguousarray(np.linalg.solve(G, J)).T
    qdd = pinv @ target
    if has_null:
        qdd = qdd + qdd_null - pinv @ (J @ qdd_null)
    return qdd


def _weighted_solve(W, JwJ, diag, rhs):
    """``(W + JᵀwJ + diag·I)⁻¹ rhs``, summed in that order (pull_through_metric's)."""
    A = W + JwJ
    for i in range(A.shape[0]):
        A[i, i] += diag
    return np.linalg.solve(A, rhs)


def _restore(W, rows, metric, out, qdd_c, JwJ, diag, rhs):
    """restore_approached: every left-out row q̈_C approaches (``a_r·q̈_C < 0``) put back
    with its metric, q̈_C solved again, until none is approached."""
    while out.any():
        back = out & (rows @ qdd_c < 0.0)
        if not back.any():
            break
        idx = np.nonzero(back)[0]
        r = rows[idx]
        W = W + (r.T * metric[idx]) @ r
        out &= ~back
        qdd_c = _weighted_solve(W, JwJ, diag, rhs)
    return qdd_c


def metric_forcing(M, f, rows, metric, J, w, target, m_null, qdd_null, has_null, qdd_free,
                   directional, task_geometry):
    """``(q̈_C, h)`` [rad/s²] (see the module): M (n, n), f (n,) the avoidance fabric's metric
    and geometry force; rows (R, n), metric (R,) its barrier rows (R may be 0); J (m, n), w,
    target t = ẍ_d − J̇q̇ (m,): PUMA's task spec; m_null, q̈_null, has_null: the secondary
    objective; qdd_free: q̈_P; task_geometry: h with PUMA's task metric as a leaf."""
    wJ = w * J
    JwJ = J.T @ wJ
    rhs = wJ.T @ target
    diag = 0.0
    if has_null and m_null > 0.0:
        diag = m_null
        rhs = rhs + m_null * qdd_null
    if directional and rows.shape[0] > 0:
        out = (rows @ qdd_free > 0.0) & (metric > 0.0)
        W = M.copy()
        if out.any():
            idx = np.nonzero(out)[0]
            r = rows[idx]
            W -= (r.T * metric[idx]) @ r
        qdd_c = _weighted_solve(W, JwJ, diag, rhs)
        qdd_c = _restore(W, rows, metric, out, qdd_c, JwJ, diag, rhs)
    else:
        qdd_c = _weighted_solve(M, JwJ, diag, rhs)
    G = M + JwJ if task_geometry else M
    return qdd_c, -np.linalg.solve(G, f)


def pulled_forcing(M, f, rows, metric, J, w, target, m_null, qdd_null, has_null, lam2,
                   directional, task_geometry):
    """``(q̈_C, h, ‖q̈_C‖² + ‖h‖²)``: :func:`metric_forcing` with its q̈_P, PUMA's free pull
    :func:`damped_pull` (λ² = lam2), computed in the same call where the directional forcing
    reads it (directional, and barrier rows); the squared norms sum tells the caller whether
    both are finite."""
    qdd_free = np.empty(0)
    if directional and rows.shape[0] > 0:
        qdd_free = damped_pull(J, target, lam2, qdd_null, has_null)
    qdd_c, h = metric_forcing(M, f, rows, metric, J, w, target, m_null, qdd_null, has_null,
                              qdd_free, directional, task_geometry)
    return qdd_c, h, qdd_c @ qdd_c + h @ h


def _meets(Av, b, x, standoff):
    """``a·v ≥ b`` on every row, with ``min(b, 0)`` on the rows at or past the standoff."""
    past = x <= standoff
    if past.any():
        return (Av >= np.where(past, np.minimum(b, 0.0), b)).all()
    return (Av >= b).all()


def _bounds(x, jdqd, dt, kappa, standoff):
    """``b = −κ(x − x_s)/Δt − ½Δt min(J̇q̇, 0)`` (barrier_step's right-hand sides)."""
    b = -kappa * (x - standoff) / dt
    return b - 0.5 * dt * np.minimum(jdqd, 0.0)


def rows_free(v, rows, x, jdqd, xd, qd, has_drift, g_rows, g_heights, g_jdqd, g_height, dt,
              kappa, standoff):
    """Whether the next velocity v (n,) [rad/s] meets every row of
    :func:`~tamedpuma.fabrics.discrete.barrier_step`, so that the step keeps it: the barrier
    rows (R, n) with x, J̇q̇ (R,), and with has_drift their drift ``ẋ − a·q̇`` (xd (R,), q̇)
    also ``a·v + drift ≥ b``; the ground rows (G, n) at heights − g_height, no drift (the
    rows stacked as the step stacks them)."""
    A = np.concatenate((rows, g_rows))
    x = np.concatenate((x, g_heights - g_height))
    b = _bounds(x, np.concatenate((jdqd, g_jdqd)), dt, kappa, standoff)
    Av = A @ v
    if not _meets(Av, b, x, standoff):
        return False
    if not has_drift:
        return True
    drift = np.concatenate((xd - rows @ qd, np.zeros(g_heights.shape[0])))
    return (Av >= b - drift).all()


def lowest_points(verts, starts, Rt, tz, radii, below):
    """Each link hull's lowest point (robot/ground.py ``_lowest_points``): hull l has the
    vertices ``verts[starts[l]:starts[l + 1]]`` (link frame), rotation R_l (given transposed,
    ``Rt[l] = R_lᵀ``: R_l in pinocchio's column-major order, so that the products take the
    same BLAS route as on pinocchio's own array), origin height tz[l] and bounding radius
    radii[l] [m]; its lowest vertex v (``min (v·R_l[2])``) counts when
    ``tz − radius < below[l]`` and its height ``tz + v·R_l[2] < below[l]`` (below (L,) [m]).
    Returns (found (L,) bool, heights (L,): the lowest point's height where computed, else
    ``tz − radius`` (a lower bound), the vertex relative to the origin in world axes R_l v
    (L, 3))."""
    L = tz.shape[0]
    found, heights, points = np.zeros(L, np.bool_), np.empty(L), np.empty((L, 3))
    for i in range(L):
        heights[i] = tz[i] - radii[i]
        if heights[i] >= below[i]:
            continue
        R = Rt[i].T
        v = verts[starts[i]:starts[i + 1]]
        z = v @ R[2]
        j = z.argmin()
        height = tz[i] + z[j]
        heights[i] = height
        if height < below[i]:
            found[i] = True
            points[i] = R @ v[j]
    return found, heights, points


def ground_reach(found, heights, below, lipschitz):
    """How far [rad] any joint may move with every hull still higher than its row height, from
    :func:`lowest_points`' results: ``min_l (x_l − below_l)/L_l`` over the hulls with
    Lipschitz constant L_l > 0 [m/rad] (x_l: the lowest point or a lower bound of it; a hull
    with L_l = 0 never moves up or down); 0 where a row was found, inf where no hull moves."""
    reach = np.inf
    for i in range(heights.shape[0]):
        if found[i]:
            return 0.0
        if lipschitz[i] > 0.0:
            reach = min(reach, (heights[i] - below[i]) / lipschitz[i])
    return reach


def ground_rows(J, acc, r, qd):
    """The rows and curvature terms of the lowest points (robot/ground.py
    ``hull_ground_rows``): J (k, 6, n) the links' world-aligned Jacobians, acc (k, 6) their
    origins' classical accelerations, r (k, 3) the points relative to the origins [m]:
    rows ``(J_p)_z + (J_ω)_x r_y − (J_ω)_y r_x`` (k, n) and the z component of
    ``a_o + α × r + ω × (ω × r)`` (k,) [m/s²]."""
    rx, ry, rz = r[:, 0], r[:, 1], r[:, 2]
    rows = (J[:, 2] + J[:, 3] * ry[:, None]) - J[:, 4] * rx[:, None]
    w = (np.ascontiguousarray(J[:, 3:]).reshape(-1, J.shape[2]) @ qd).reshape(-1, 3)  # ω
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    w_r = (wx * rx + wy * ry) + wz * rz
    w_w = (wx * wx + wy * wy) + wz * wz
    return rows, acc[:, 2] + acc[:, 3] * ry - acc[:, 4] * rx + wz * w_r - rz * w_w


def hull_ground(S, qd_chain, parents, Rf, pf, support, verts, starts, radii, below, lipschitz,
                qd):
    """The ground rows of the hulls in one call (:mod:`~tamedpuma.methods._ground_rows`): the
    hull frames' placements, Jacobians and J̇q̇ from the chain's joint state S at q̇_chain
    (:func:`~tamedpuma.robot.point_motion.frame_motion`, its frame table parents, R_f, p_f,
    support), each hull's lowest point (:func:`lowest_points`; hull l's vertices
    ``verts[starts[l]:starts[l + 1]]``, radii, below (L,)) and, for the hulls found, the rows and
    curvature terms (:func:`ground_rows` at qd): the same arithmetic, array for array, as
    those calls one by one. Returns (heights (k,), rows (k, n), J̇q̇ (k,), the reach of
    :func:`ground_reach` (lipschitz (L,) [m/rad]))."""
    R, p, J, acc = frame_motion(S, qd_chain, parents, Rf, pf, support, 6)
    L = parents.shape[0]
    Rt, tz = np.empty((L, 3, 3)), np.empty(L)
    for i in range(L):
        Rt[i] = R[i].T
        tz[i] = p[i, 2]
    found, heights, points = lowest_points(verts, starts, Rt, tz, radii, below)
    links = np.nonzero(found)[0]
    k = links.shape[0]
    Jk, acck = np.empty((k, 6, J.shape[2])), np.empty((k, 6))
    rk, hk = np.empty((k, 3)), np.empty(k)
    for i in range(k):
        j = links[i]
        Jk[i], acck[i], rk[i], hk[i] = J[j], acc[j], points[j], heights[j]
    rows, jdqd = ground_rows(Jk, acck, rk, qd)
    return hk, rows, jdqd, ground_reach(found, heights, below, lipschitz)


def null_pull(S, qd_chain, parents, Rf, pf, support, target, stiffness, damping, qd):
    """The elbow objective ``q̈_null = k J_linkᵀ (p* − p_link) − d q̇`` [rad/s²]
    (:class:`~tamedpuma.methods._policy.NullSpaceObjective`): the link's origin p_link [m] and
    position Jacobian J_link (3, n) from the chain's joint state S at q̇_chain
    (:func:`~tamedpuma.robot.point_motion.frame_motion` of the link's frame table parents, R_f,
    p_f, support), target p* (3,) [m], stiffness k [1/s²], damping d [1/s]; the product
    ``(k J)ᵀ e`` on the transposed array, as ``k Jᵀ @ e`` takes it."""
    _, p, J, _ = frame_motion(S, qd_chain, parents, Rf, pf, support, 3)
    e = target - p[0]
    return np.dot((stiffness * J[0]).T, e) - damping * qd


def energized_alpha(M, f_energy, qd, qdd, eps):
    """``(α, M q̇)``: ``α = q̇ᵀ(M q̈ + f_L)/(q̇ᵀ M q̇ + ε)`` [1/s] (AvoidanceFabric.alpha), M (n, n)
    the energy's metric, f_L (n,) its force, ε [(rad/s)²]."""
    Mqd = np.dot(M, qd)
    return (np.dot(Mqd, qdd) + np.dot(qd, f_energy)) / (np.dot(qd, Mqd) + eps), Mqd


def fpm_velocity(M, f_energy, qd, h, qdd_c, eps, dt, semi_implicit):
    """FPM's next velocity before the filters: ``(α, q̇⁺)`` with α energizing h
    (:func:`energized_alpha`) and ``q̇⁺`` of ``q̈ = h − α q̇ + q̈_C`` over Δt [s], the ``α q̇``
    part implicit along q̇ (semi_implicit:
    :func:`~tamedpuma.fabrics.discrete.energized_velocity_step`) or explicit:
    ``q̇ + Δt (h − α q̇ + q̈_C)``."""
    alpha, Mqd = energized_alpha(M, f_energy, qd, h, eps)
    if semi_implicit:
        return alpha, energized_velocity_step(qd, h + qdd_c, alpha, dt, Mqd, eps)
    return alpha, qd + dt * (h - alpha * qd + qdd_c)


def cpm_velocity(M, f_energy, qd, h, qdd_c, dpsi, eps, regulator_scale, beta_min, matched,
                 semi_implicit, dt):
    """CPM's law (paper variant) up to the filters: ``q̈ = (h + q̈_C) + c q̇`` with
    ``c = r − α − β``, the regulator ``r = −s q̇ᵀ∂ψ/(q̇ᵀMq̇ + ε)``, α energizing h + q̈_C and
    β the damping (matched: ``max(β_min, r − α)``); with semi_implicit and c < 0 the ``c q̇``
    part implicit along q̇ and ``q̈ = (q̇⁺ − q̇)/Δt``. Returns (α, β, q̇ + Δt q̈ [rad/s],
    β q̇ᵀMq̇, ∂ψ·q̇)."""
    h_plus_f = h + qdd_c
    alpha, Mqd = energized_alpha(M, f_energy, qd, h_plus_f, eps)
    qMq = np.dot(qd, Mqd)
    r_coef = -regulator_scale * np.dot(qd, dpsi) / (qMq + eps)
    beta = beta_min
    if matched and r_coef - alpha > beta_min:
        beta = r_coef - alpha
    c = r_coef - alpha - beta
    if semi_implicit and c < 0.0:
        qd_next = energized_velocity_step(qd, h_plus_f, -c, dt, Mqd, eps)
        qdd = (qd_next - qd) / dt
    else:
        qdd = h_plus_f + c * qd
    return alpha, beta, qd + dt * qdd, beta * qMq, np.dot(dpsi, qd)


KERNELS = (damped_pull, metric_forcing, pulled_forcing, rows_free, lowest_points, ground_rows,
           ground_reach, hull_ground, null_pull, fpm_velocity, cpm_velocity, limit_speed)
HELPERS = (_weighted_solve, _restore, _meets, _bounds, lowest_points, ground_rows, ground_reach,
           frame_motion, damped_pull, metric_forcing, energized_alpha, energized_velocity_step)


class Kernel:
    """One kernel: its compiled version where :func:`warm_up` made one (frozen: it compiles
    nothing more), else the plain function. A call the compiled version cannot take runs the
    plain function, whose numbers and errors are numpy's: argument types the warm-up did not
    see (numba's TypeError, whose message alone costs ~1 ms: the kernel then stays plain for
    the rest of the process, ``demoted`` saying why), or an error inside it (e.g. a singular or
    non-finite system, which numba reports differently: this call only)."""

    def __init__(self, plain):
        self.plain, self.fast, self.demoted = plain, None, None

    def __call__(self, *args):
        if self.fast is not None:
            try:
                return self.fast(*args)
            except TypeError as exc:
                self.fast, self.demoted = None, str(exc).split("\n")[0]
            except Exception:  # noqa: BLE001 - the plain function answers (or raises) as numpy
                pass
        return self.plain(*args)


#: the kernels the step calls, by name
STEP = {k.__name__: Kernel(k) for k in KERNELS}


def _compiled():
    """The kernels compiled by numba (helpers resolved to compiled copies in a namespace of
    their own, so the plain functions stay plain); loaded from numba's on-disk cache after the
    first time."""
    from tamedpuma.jit import compile_kernels

    return compile_kernels(globals(), KERNELS, HELPERS)


def warm_up() -> bool:
    """Compile the kernels (or load them from the cache) with the argument types of a step,
    then freeze them; once per process. Whether they are compiled (False without numba, or
    where numba fails to import or compile here: then, with a warning, every call is plain)."""
    from tamedpuma.jit import compile_once

    return compile_once(_COMPILED, _install, AVAILABLE, "the step kernels",
                        "the step runs them as plain numpy") is not None


def _install() -> dict:
    """The kernels compiled, called once with a step's argument types, frozen and set as
    :data:`STEP`'s compiled copies; by name."""
    kernels = _compiled()
    with warnings.catch_warnings():  # numba's notes on non-contiguous products
        warnings.simplefilter("ignore")
        _first_calls(kernels)
    for name, fast in kernels.items():
        fast.disable_compile()
        STEP[name].fast = fast
    return kernels


def _first_calls(kernels: dict, n: int = 7, m: int = 6) -> None:
    """One call of each kernel per argument-type combination a step passes (C-contiguous
    float64 arrays, bools, floats): numba compiles (or loads) each signature here."""
    rng = np.random.default_rng(0)
    J, t, v = rng.standard_normal((m, n)), rng.standard_normal(m), rng.standard_normal(n)
    M = np.eye(n) + 0.1 * np.ones((n, n))
    rows, none, metric = rng.standard_normal((3, n)), np.empty((0, n)), np.ones(3)
    kernels["damped_pull"](J, t, 1e-4, v, True)
    for r, mt in ((rows, metric), (none, np.empty(0))):
        kernels["metric_forcing"](M, v, r, mt, J, 100.0, t, 0.05, v, True, v, True, True)
        kernels["pulled_forcing"](M, v, r, mt, J, 100.0, t, 0.05, v, True, 1e-4, True, True)
    k3 = rng.standard_normal((4, 3))
    three = np.eye(3).reshape(1, 3, 3).repeat(2, 0)
    kernels["lowest_points"](k3, np.array([0, 2, 4]), three, np.ones(2), np.ones(2),
                             np.full(2, 2.0))
    kernels["ground_rows"](rng.standard_normal((2, 6, n)), k3[:2].repeat(2, 1), k3[:2], v)
    kernels["rows_free"](v, rows, metric, metric, metric, v, True, none, np.empty(0),
                         np.empty(0), 0.01, 0.02, 0.5, 1e-3)
    S = rng.standard_normal((n, 7, 3))
    table = (np.arange(2, dtype=np.int64), three, k3[:2], np.ones((2, n), np.bool_))
    kernels["hull_ground"](S, v, *table, k3, np.array([0, 2, 4]), np.ones(2), np.full(2, 2.0),
                           np.ones(2), v)
    kernels["ground_reach"](np.zeros(2, np.bool_), np.ones(2), np.ones(2), np.ones(2))
    kernels["null_pull"](S, v, *(a[:1] for a in table), t[:3], 1.0, 2.0, v)
    kernels["limit_speed"](v, np.ones(n))
    for semi in (True, False):
        kernels["fpm_velocity"](M, v, v, v, v, 1e-6, 0.02, semi)
        kernels["cpm_velocity"](M, v, v, v, v, v, 1e-6, 1.0, 0.5, semi, semi, 0.02)
