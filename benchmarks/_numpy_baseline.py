"""The original's way, for the throughput benchmarks: per grasp and per Monte-Carlo sample, NumPy contact
finding on the distance grid and one small wrench-resistance problem per sample, solved one at a time.

Same physics and parameters as dexjax (so the comparison is like for like), written the way Dex-Net runs it:
one grasp, one sample, one solve at a time. Contact finding is vectorised over a jaw's line samples (more
generous than Dex-Net's Python loop over them). Two solvers for the wrench-resistance step (``solver=``):

* ``'cvxopt'`` (Dex-Net's own): a cvxopt interior-point QP per problem with **cvxopt's default tolerances**
  (abstol 1e-7, reltol 1e-6, feastol 1e-7, 100 iterations); like Dex-Net's ``quality.py``, this module only
  silences the progress output (``cvxopt.solvers.options['show_progress'] = False``). Parallel jaw:
  min ||G a - t||^2 + ||e||^2 over a >= 0, e >= 0, C a - e <= c (the per-finger force limit with its excess
  paid in the residual, dexjax's semantics; Dex-Net itself makes the limit hard and adds a 1e-10 ridge).
  Suction: the spec's 6-variable QP with 11 linear inequalities (contact-frame force and torque).
* ``'nnls'`` (a stronger plain baseline): the same problems posed as dexjax poses them, as a non-negative
  least-squares problem lifted with one slack per force-limit group (`lift`, a NumPy copy of
  ``dexjax.quality.wrench.lift_bounded_groups``), each solved by ``scipy.optimize.nnls`` (Lawson--Hanson in
  compiled code, float64). Suction uses dexjax's polyhedral form of the same constraint set
  (``dexjax.contacts.suction.suction_wrenches``: 8 cone generators and two bounded +/- elastic-torque pairs).

Both solvers see exactly the same random draws and contacts (the random generator is consumed before the
solve), so their per-sample decisions can be compared directly. ``problems=`` collects each solved problem
(`WrenchProblem`) for a solver-only comparison.

Without cvxopt the module still imports: ``CVXOPT_MISSING`` says why, `available_solvers` leaves ``'cvxopt'`` out
and asking for it raises `ModuleNotFoundError`; ``'nnls'`` needs only SciPy.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import scipy.optimize

try:
  import cvxopt  # pylint: disable=g-import-not-at-top
except ImportError as e:  # the nnls baseline needs only SciPy
  cvxopt = None
  CVXOPT_MISSING = f"{type(e).__name__}: {e}"
else:
  CVXOPT_MISSING = None
  # Dex-Net's setting: progress output off, cvxopt's default tolerances kept (not tightened).
  cvxopt.solvers.options["show_progress"] = False

SOLVERS = ("cvxopt", "nnls")


def available_solvers() -> tuple[str, ...]:
  """The `SOLVERS` whose packages are installed."""
  return SOLVERS if cvxopt is not None else ("nnls",)


def _check_solver(solver: str) -> None:
  if solver not in SOLVERS:
    raise ValueError(f"solver: expected one of {SOLVERS}, got {solver!r}")
  if solver == "cvxopt" and cvxopt is None:
    raise ModuleNotFoundError(f"the cvxopt baseline needs cvxopt ({CVXOPT_MISSING})")

_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)))


class NumpyObject:
  def __init__(self, model):
    self.sdf = np.asarray(model.sdf, np.float64)
    self.grad = np.asarray(model.sdf_grad, np.float64)
    self.origin = np.asarray(model.origin, np.float64)
    self.dx = float(model.voxel_size)
    self.com = np.asarray(model.center_of_mass, np.float64)
    self.d = self.sdf.shape[0]

  def _interp(self, grid, x):
    g = (x - self.origin) / self.dx
    gc = np.clip(g, 0, self.d - 1)
    out = np.linalg.norm(g - gc, axis=-1) * self.dx
    i0 = np.clip(np.floor(gc), 0, self.d - 2).astype(int)
    f = gc - i0
    val = 0.0
    for c in _CORNERS:
      w = np.prod(np.where(c == 1, f, 1 - f), axis=-1)
      idx = i0 + c
      v = grid[idx[..., 0], idx[..., 1], idx[..., 2]]
      val = val + (w[..., None] * v if v.ndim > w.ndim else w * v)
    return val, out

  def phi(self, x):
    v, out = self._interp(self.sdf, x)
    return v + out

  def normal(self, x):
    g, _ = self._interp(self.grad, x)
    return g / max(np.linalg.norm(g), 1e-12)


def _crossing(obj, start, direction, length, n, exiting=False):
  ts = np.linspace(0, length, n)
  phi = obj.phi(start + ts[:, None] * direction) * (-1 if exiting else 1)
  beyond = phi <= 0
  if beyond[0] or not beyond.any():
    return None, bool(beyond[0])
  k = int(np.argmax(beyond))
  ta, tb, fa, fb = ts[k - 1], ts[k], phi[k - 1], phi[k]
  for _ in range(3):
    t = ta + fa * (tb - ta) / (fa - fb)
    ft = obj.phi(start + t * direction) * (-1 if exiting else 1)
    if ft > 0:
      ta, fa, fb = t, ft, fb * 0.5
    else:
      tb, fb, fa = t, ft, fa * 0.5
  return ta + fa * (tb - ta) / (fa - fb), False


def _tangents(n):
  ref = np.array([1.0, 0, 0]) if abs(n[0]) < 0.99 else np.array([0, 1.0, 0])
  t1 = ref - ref.dot(n) * n
  t1 /= np.linalg.norm(t1)
  return t1, np.cross(n, t1)


@dataclasses.dataclass(frozen=True)
class WrenchProblem:
  """One wrench-resistance problem as each solver receives it.

  Attributes:
    kind: ``'parallel_jaw'`` or ``'suction'``.
    cvxopt_args: the arguments of `pj_residual_cvxopt` or `suction_residual_cvxopt`.
    a, b: the lifted NNLS system, (6 + k, n + k) and (6 + k,) float64 (8 x 22 parallel jaw, 8 x 14 suction).
  """

  kind: str
  cvxopt_args: tuple
  a: np.ndarray
  b: np.ndarray

  def residual(self, solver: str) -> float:
    """The residual (N) with ``solver`` (``'cvxopt'`` or ``'nnls'``)."""
    if solver == "nnls":
      return nnls_residual(self.a, self.b)
    fn = pj_residual_cvxopt if self.kind == "parallel_jaw" else suction_residual_cvxopt
    return fn(*self.cvxopt_args)


def pj_residual_cvxopt(G, t, groups, limits):
  """min ||G a - t||^2 + ||e||^2, a >= 0, e >= 0, groups a - e <= limits (cvxopt, default tolerances)."""
  n, k = G.shape[1], groups.shape[0]
  P = np.zeros((n + k, n + k))
  P[:n, :n] = G.T @ G
  P[n:, n:] = np.eye(k)
  q = np.concatenate([-G.T @ t, np.zeros(k)])
  Gi = np.vstack([-np.eye(n + k), np.hstack([groups, -np.eye(k)])])
  h = np.concatenate([np.zeros(n + k), limits])
  sol = cvxopt.solvers.qp(cvxopt.matrix(2 * P), cvxopt.matrix(2 * q), cvxopt.matrix(Gi), cvxopt.matrix(h))
  x = np.array(sol["x"]).ravel()
  return float(np.sqrt(max(np.sum((G @ x[:n] - t) ** 2) + np.sum(x[n:] ** 2), 0.0)))


def suction_residual_cvxopt(A, b, mu, r, V, elastic):
  """min ||A z - b|| over the spec's 11 inequalities on z = (f, tau) (cvxopt, default tolerances).

  A (6, 6) maps contact-frame force and torque to the scaled object wrench; b (6,) is the target; ``mu``
  friction, ``r`` cup radius (m), ``V`` vacuum force (N), ``elastic`` = pi r kappa (N m).
  """
  k3, k2 = np.sqrt(3), np.sqrt(2)
  Gi, hi = [], []
  for sg in (1, -1):
    Gi += [[sg * k3, 0, -mu, 0, 0, 0], [0, sg * k3, -mu, 0, 0, 0], [0, 0, -mu * r, 0, 0, sg * k3],
           [0, 0, 0, sg * k2, 0, 0], [0, 0, 0, 0, sg * k2, 0]]
    hi += [mu * V, mu * V, mu * r * V, elastic, elastic]
  Gi.append([0, 0, -1, 0, 0, 0])
  hi.append(V)
  sol = cvxopt.solvers.qp(cvxopt.matrix(2 * A.T @ A), cvxopt.matrix(-2 * A.T @ b), cvxopt.matrix(np.array(Gi, float)),
                          cvxopt.matrix(np.array(hi, float)))
  z = np.array(sol["x"]).ravel()
  return float(np.linalg.norm(A @ z - b))


def lift(G, t, groups, limits):
  """The lifted NNLS system [[G, 0], [groups, I]] x = [t; limits] (``dexjax.quality.wrench.lift_bounded_groups``
  in float64): min_{x >= 0} ||A x - b|| = sqrt(min_{a >= 0} ||G a - t||^2 + ||max(0, groups a - limits)||^2)."""
  k = groups.shape[0]
  A = np.block([[G, np.zeros((G.shape[0], k))], [groups, np.eye(k)]])
  return A, np.concatenate([t, limits])


def nnls_residual(A, b):
  """min_{x >= 0} ||A x - b|| by ``scipy.optimize.nnls`` (Lawson--Hanson, float64, SciPy's defaults)."""
  return float(scipy.optimize.nnls(A, b)[1])


def suction_nnls_system(p, v, b1, b2, com, mu, gripper, s, w):
  """dexjax's suction problem (``suction_wrenches``) in NumPy, lifted: (A (8, 14), b (8,)).

  ``p`` contact, ``v`` approach, (b1, b2) tangents, ``com`` centre of mass, ``mu`` friction, ``s`` torque
  scale, ``w`` (6,) external wrench (force N, torque N m, unscaled).
  """
  r, k3 = gripper.cup_radius, np.sqrt(3)
  rot = np.stack([b1, b2, v], 1)
  signs = np.array(list(itertools.product((1.0, -1.0), repeat=3)))
  local_f = np.stack([signs[:, 0] * mu / k3, signs[:, 1] * mu / k3, np.ones(8)], 1)
  forces = local_f @ rot.T
  arm = p - com
  torques = s * ((signs[:, 2] * mu * r / k3)[:, None] * v[None] + np.cross(arm, forces))
  limit = np.pi * r * gripper.elastic_limit / np.sqrt(2)
  elastic = np.concatenate([np.zeros((4, 3)), s * limit * np.stack([b1, -b1, b2, -b2])], 1)
  G = np.concatenate([np.concatenate([forces, torques], 1), elastic], 0).T
  bound = s * limit
  groups = bound * np.concatenate([np.zeros((2, 8)), np.kron(np.eye(2), np.ones((1, 2)))], 1)
  vacuum = gripper.vacuum_force * np.concatenate([v, s * np.cross(arm, v)])
  t = -np.concatenate([w[:3], s * w[3:]]) + vacuum
  return lift(G, t, groups, np.full(2, bound))


def _sample_conditions(rng, pert, approach):
  shape = pert.mass_mean**2 / pert.mass_variance
  mass = rng.gamma(shape, pert.mass_variance / pert.mass_mean)
  std = np.sqrt(pert.friction_variance)
  while True:
    mu = rng.normal(pert.friction_mean, std)
    if 0 <= mu <= 1:
      break
  while True:  # rejection sampling on the sphere, as the seed describes
    g = rng.normal(size=3)
    g /= np.linalg.norm(g)
    if np.arccos(np.clip(g @ approach, -1, 1)) <= pert.gravity_cone_angle:
      break
  return mass, mu, g, pert.disturbance_sigma * rng.normal(size=6)


def parallel_jaw_robust(obj, center, axis, approach, width, gripper, pert, cfg, rng, *, solver="cvxopt",
                        problems=None):
  """Robust parallel-jaw probability of one grasp (M = ``pert.num_samples``), one sample and solve at a time.

  ``solver``: ``'cvxopt'`` or ``'nnls'`` (see the module docstring); ``problems``: a list that collects every
  solved `WrenchProblem`, or None.
  """
  _check_solver(solver)
  wins = 0
  for _ in range(pert.num_samples):
    c = center + pert.position_sigma * rng.normal(size=3)
    mass, mu, g, dist = _sample_conditions(rng, pert, approach)
    half = 0.5 * width
    pts, nrm, dirs = [], [], []
    ok = True
    for start, d in ((c - half * axis, axis), (c + half * axis, -axis)):
      t, _ = _crossing(obj, start, d, half - 0.5 * gripper.min_width, gripper.num_line_samples)
      if t is None:
        ok = False
        break
      p = start + t * d
      pts.append(p), nrm.append(-obj.normal(p)), dirs.append(d)
    if not ok:
      continue
    cols = []
    for p, n, d in zip(pts, nrm, dirs):
      beta = max(d @ n, 0.0)
      if mu * beta < np.sqrt(max(1 - beta**2, 0)) or beta <= 0:
        ok = False
      t1, t2 = _tangents(n)
      for j in range(gripper.num_cone_edges):
        a = 2 * np.pi * j / gripper.num_cone_edges
        f = beta * (n + mu * (np.cos(a) * t1 + np.sin(a) * t2))
        cols.append(np.concatenate([f, cfg.torque_scale * np.cross(p - obj.com, f)]))
      tor = cfg.torque_scale * beta * (2 / 3) * mu * gripper.finger_radius * n
      cols += [np.concatenate([np.zeros(3), tor]), np.concatenate([np.zeros(3), -tor])]
    if not ok:
      continue
    G = np.stack(cols, 1)
    m = gripper.num_cone_edges + 2
    groups = np.kron(np.eye(2), np.ones((1, m)))
    w = dist + np.concatenate([mass * cfg.gravity_acceleration * g, np.zeros(3)])
    target = -np.concatenate([w[:3], cfg.torque_scale * w[3:]])
    limits = np.full(2, gripper.force_limit)
    if solver == "cvxopt":
      residual = pj_residual_cvxopt(G, target, groups, limits)
    else:
      residual = nnls_residual(*lift(G, target, groups, limits))
    if problems is not None:
      problems.append(WrenchProblem("parallel_jaw", (G, target, groups, limits), *lift(G, target, groups, limits)))
    wins += residual <= cfg.tolerance
  return wins / pert.num_samples


def _ray(obj, origin, v, steps, max_dist):
  lo = obj.origin - 0.5 * obj.dx
  hi = lo + obj.d * obj.dx
  safe = np.where(np.abs(v) > 1e-9, v, 1e-9)
  ta, tb = (lo - origin) / safe, (hi - origin) / safe
  t = max(np.max(np.minimum(ta, tb)), 0.0)
  t_exit = min(np.min(np.maximum(ta, tb)), max_dist)
  for _ in range(steps):
    ph = obj.phi(origin + t * v)
    if ph < 0.01 * obj.dx or t > t_exit:
      break
    t += max(ph, 0.1 * obj.dx)
  p = origin + t * v
  ph = obj.phi(p)
  slope = obj.normal(p) @ v
  t += np.clip(-ph / min(slope, -0.1), -obj.dx, obj.dx)
  return t, bool(ph < 0.1 * obj.dx and t <= t_exit)


def suction_robust(obj, center, approach, gripper, pert, cfg, rng, *, solver="cvxopt", problems=None):
  """Robust suction probability of one grasp; ``solver`` and ``problems`` as in `parallel_jaw_robust`."""
  _check_solver(solver)
  wins = 0
  r, h, n, q = gripper.cup_radius, gripper.cone_height, gripper.num_ring_vertices, gripper.num_edge_subsamples + 1
  for _ in range(pert.num_samples):
    c = center + pert.position_sigma * rng.normal(size=3)
    mass, mu, g, dist = _sample_conditions(rng, pert, approach)
    v = approach / np.linalg.norm(approach)
    back = 2 * obj.d * obj.dx
    t, hit = _ray(obj, c - back * v, v, 2 * gripper.num_ray_steps, np.inf)
    if not hit or abs(t - back) > gripper.contact_tolerance:
      continue
    p = c - back * v + t * v
    b1, b2 = _tangents(v)
    ang = 2 * np.pi * np.arange(n) / n
    verts = r * (np.cos(ang)[:, None] * b1 + np.sin(ang)[:, None] * b2)
    reach = h + r
    lip, depth, ok = [], [], True
    for i in range(n):
      for k in range(q):
        x = p + verts[i] + (k / q) * (verts[(i + 1) % n] - verts[i])
        t, hit = _ray(obj, x - reach * v, v, gripper.num_ray_steps, 2 * reach)
        ok &= hit
        lip.append(x - reach * v + t * v), depth.append(t - reach)
    if not ok:
      continue
    lip, depth = np.array(lip).reshape(n, q, 3), np.array(depth).reshape(n, q)
    delta = depth[:, 0].mean() - h
    for i in range(n):
      t, hit = _ray(obj, p + 0.5 * verts[i] - reach * v, v, gripper.num_ray_steps, 2 * reach)
      ok &= hit and (t - reach) > min(delta, 0)
    if not ok:
      continue
    apex = p + min(delta, 0) * v
    ring = np.concatenate([lip.reshape(-1, 3), lip[:1, 0]])
    per = np.linalg.norm(np.diff(ring, axis=0), axis=1).reshape(n, q).sum(1)
    vp = lip[:, 0]
    flex = np.linalg.norm(vp - np.roll(vp, -2, 0), axis=1)
    cone = np.linalg.norm(vp - apex, axis=1)
    rest = [2 * r * np.sin(np.pi / n), 2 * r * np.sin(2 * np.pi / n), np.hypot(r, h)]
    strain = max(np.abs(per / rest[0] - 1).max(), np.abs(flex / rest[1] - 1).max(), np.abs(cone / rest[2] - 1).max())
    if strain > gripper.max_strain:
      continue
    # Wrench resistance: the spec's inequality form (contact-frame force and torque) for cvxopt, dexjax's
    # polyhedral form lifted to an NNLS for scipy.
    R = np.stack([b1, b2, v], 1)
    s = cfg.torque_scale
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, :3] = s * np.cross(p - obj.com, R.T).T
    A[3:, 3:] = s * R
    w = dist + np.concatenate([mass * cfg.gravity_acceleration * g, np.zeros(3)])
    b = -np.concatenate([w[:3], s * w[3:]])
    args = (A, b, mu, r, gripper.vacuum_force, np.pi * r * gripper.elastic_limit)
    if solver == "cvxopt":
      residual = suction_residual_cvxopt(*args)
    else:
      residual = nnls_residual(*suction_nnls_system(p, v, b1, b2, obj.com, mu, gripper, s, w))
    if problems is not None:
      problems.append(WrenchProblem("suction", args, *suction_nnls_system(p, v, b1, b2, obj.com, mu, gripper, s, w)))
    wins += residual <= cfg.tolerance
  return wins / pert.num_samples
