"""The original's way, for the throughput benchmark: per grasp and per Monte-Carlo sample, NumPy contact
finding on the distance grid and a general-purpose QP (cvxopt, as Dex-Net) for wrench resistance.

Same physics and parameters as dexjax (so the comparison is like for like), written the way Dex-Net runs it:
one grasp, one sample, one QP at a time. Contact finding is vectorised over a jaw's line samples (more
generous than Dex-Net's Python loop over them).
"""

from __future__ import annotations

import itertools

import cvxopt
import numpy as np

cvxopt.solvers.options["show_progress"] = False
cvxopt.solvers.options["abstol"] = 1e-10
cvxopt.solvers.options["reltol"] = 1e-10
cvxopt.solvers.options["feastol"] = 1e-10

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


def _qp_residual(G, t, groups, limits):
  """min ||G a - t||^2 + ||e||^2, a >= 0, e >= 0, groups a - e <= limits (cvxopt)."""
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


def parallel_jaw_robust(obj, center, axis, approach, width, gripper, pert, cfg, rng):
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
    wins += _qp_residual(G, target, groups, np.full(2, gripper.force_limit)) <= cfg.tolerance
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


def suction_robust(obj, center, approach, gripper, pert, cfg, rng):
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
    # Wrench resistance on the spec's inequality form (contact-frame force and torque), cvxopt.
    R = np.stack([b1, b2, v], 1)
    s = cfg.torque_scale
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, :3] = s * np.cross(p - obj.com, R.T).T
    A[3:, 3:] = s * R
    w = dist + np.concatenate([mass * cfg.gravity_acceleration * g, np.zeros(3)])
    b = -np.concatenate([w[:3], s * w[3:]])
    V, k3, k2 = gripper.vacuum_force, np.sqrt(3), np.sqrt(2)
    Gi, hi = [], []
    for sg in (1, -1):
      Gi += [[sg * k3, 0, -mu, 0, 0, 0], [0, sg * k3, -mu, 0, 0, 0], [0, 0, -mu * r, 0, 0, sg * k3],
             [0, 0, 0, sg * k2, 0, 0], [0, 0, 0, 0, sg * k2, 0]]
      hi += [mu * V, mu * V, mu * r * V, np.pi * r * gripper.elastic_limit, np.pi * r * gripper.elastic_limit]
    Gi.append([0, 0, -1, 0, 0, 0])
    hi.append(V)
    sol = cvxopt.solvers.qp(cvxopt.matrix(2 * A.T @ A), cvxopt.matrix(-2 * A.T @ b), cvxopt.matrix(np.array(Gi, float)),
                            cvxopt.matrix(np.array(hi, float)))
    z = np.array(sol["x"]).ravel()
    wins += np.linalg.norm(A @ z - b) <= cfg.tolerance
  return wins / pert.num_samples
