"""Contact models against exact geometry and plain NumPy re-implementations of the spec's formulas."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.contacts import close_jaws, in_friction_cone, soft_finger_wrenches, suction_seal, suction_wrenches
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.wrench import wrench_residual

PJ = ParallelJawGripper()
CUP = SuctionGripper()


def _pj(center, axis, width=0.05, approach=(0.0, 0.0, -1.0)):
  return ParallelJawGrasp(center=jnp.asarray(center, jnp.float32), axis=jnp.asarray(axis, jnp.float32),
                          approach=jnp.asarray(approach, jnp.float32), width=jnp.float32(width))


_close = jax.jit(close_jaws)
_seal = jax.jit(suction_seal)


def test_jaws_close_on_opposite_cube_faces(cube):
  c = _close(cube, _pj([0.0, 0.004, -0.003], [1.0, 0.0, 0.0]), PJ)
  assert bool(c.valid)
  np.testing.assert_allclose(np.asarray(c.points), [[-0.02, 0.004, -0.003], [0.02, 0.004, -0.003]], atol=3e-5)
  np.testing.assert_allclose(np.asarray(c.normals), [[1, 0, 0], [-1, 0, 0]], atol=1e-3)
  np.testing.assert_allclose(np.asarray(c.directions), [[1, 0, 0], [-1, 0, 0]], atol=1e-6)


def test_jaws_that_start_inside_collide_and_jaws_beside_the_object_miss(cube):
  narrow = _close(cube, _pj([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], width=0.03), PJ)
  assert bool(jnp.all(narrow.collision)) and not bool(narrow.valid)
  beside = _close(cube, _pj([0.0, 0.03, 0.0], [1.0, 0.0, 0.0]), PJ)
  assert not bool(jnp.any(beside.found)) and not bool(beside.valid)


@pytest.mark.parametrize("angle_deg,mu,expect", [(10, 0.5, True), (26, 0.5, True), (27, 0.5, False),
                                                 (38, 0.8, True), (39.5, 0.8, False), (95, 1.0, False)])
def test_friction_cone_boundary_is_arctan_mu(angle_deg, mu, expect):
  a = np.deg2rad(angle_deg)
  normal = jnp.array([np.cos(a), np.sin(a), 0.0], jnp.float32)
  assert bool(in_friction_cone(normal, jnp.array([1.0, 0.0, 0.0]), jnp.float32(mu))) == expect


def _soft_finger_reference(points, normals, dirs, com, mu, r_f, s, m=8):
  """Column-by-column NumPy version of spec sections 4.1-4.3 with our torsion gamma = 2/3 mu r_f."""
  cols = []
  for p, n, d in zip(points, normals, dirs):
    beta = max(float(np.dot(d, n)), 0.0)
    t1 = np.array([1.0, 0, 0]) - n[0] * n  # x projected onto the tangent plane (Dex-Net), however close to x
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    for j in range(m):
      f = beta * (n + mu * (np.cos(2 * np.pi * j / m) * t1 + np.sin(2 * np.pi * j / m) * t2))
      cols.append(np.concatenate([f, s * np.cross(p - com, f)]))
    tor = s * beta * (2.0 / 3.0) * mu * r_f * n
    cols.append(np.concatenate([np.zeros(3), tor]))
    cols.append(np.concatenate([np.zeros(3), -tor]))
  return np.stack(cols, axis=1)


def _dexnet_tangents(n, samples=1000):
  """Dex-Net's `Contact3D.tangents(align_axes=True)`: an SVD basis of the plane normal to the inward direction,
  then the first of ``samples`` azimuths with the largest inner product with x."""
  direction = -n
  u = np.linalg.svd(direction.reshape(3, 1))[0]
  x, y = u[:, 1], u[:, 2]
  if np.cross(x, y).dot(direction) < 0:
    y = -y
  best, best_theta = 0.0, 0.0
  for theta in 2 * np.pi * np.arange(samples) / samples:
    v = np.cos(theta) * x + np.sin(theta) * y
    if v[0] > best:
      best, best_theta = v[0], theta
  return np.cos(best_theta) * x + np.sin(best_theta) * y


def _near_x_normals(rng, count):
  """Unit normals, half of them within 10 degrees of +-x (where a y-axis fallback would differ from Dex-Net)."""
  n = rng.normal(size=(count, 3))
  n[: count // 2, 1:] *= rng.uniform(1e-3, 0.1, (count // 2, 1))
  n[: count // 2, 0] = np.sign(n[: count // 2, 0]) * (np.abs(n[: count // 2, 0]) + 1.0)
  return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_friction_cone_tangent_is_dexnets_x_aligned_tangent():
  from dexjax.geometry.transforms import aligned_tangent_basis
  normals = _near_x_normals(np.random.default_rng(1), 40)
  t1, t2 = jax.vmap(aligned_tangent_basis)(jnp.asarray(normals, jnp.float32))
  t1, t2 = np.asarray(t1, np.float64), np.asarray(t2, np.float64)
  for n, a, b in zip(normals, t1, t2):
    # Dex-Net's search over 1,000 azimuths lands within half a step (0.18 degrees) of our exact projection.
    angle = np.degrees(np.arccos(np.clip(np.dot(a, _dexnet_tangents(n)), -1.0, 1.0)))
    assert angle <= 0.19, (n, angle)
    np.testing.assert_allclose([np.dot(a, n), np.dot(b, n), np.dot(a, b)], 0.0, atol=1e-5)
    np.testing.assert_allclose(b, np.cross(n, a), atol=1e-5)
  # Along x itself the projection vanishes: a valid frame all the same.
  a, b = aligned_tangent_basis(jnp.array([1.0, 0.0, 0.0]))
  np.testing.assert_allclose([float(jnp.linalg.norm(a)), float(jnp.dot(a, b)), float(a[0])], [1.0, 0.0, 0.0],
                             atol=1e-6)


def test_soft_finger_wrenches_match_reference():
  rng = np.random.default_rng(0)
  for _ in range(10):
    points = rng.uniform(-0.03, 0.03, (2, 3))
    normals = _near_x_normals(rng, 2) if _ % 2 else rng.normal(size=(2, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    dirs = normals + 0.3 * rng.normal(size=(2, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    com, mu = rng.uniform(-0.01, 0.01, 3), rng.uniform(0.2, 1.0)
    from dexjax.contacts.parallel_jaw import JawContacts
    contacts = JawContacts(points=jnp.asarray(points, jnp.float32), normals=jnp.asarray(normals, jnp.float32),
                           directions=jnp.asarray(dirs, jnp.float32), found=jnp.ones(2, bool),
                           collision=jnp.zeros(2, bool))
    g, groups, limits = soft_finger_wrenches(contacts, jnp.asarray(com, jnp.float32), jnp.float32(mu), PJ, 100.0)
    ref = _soft_finger_reference(points, normals, dirs, com, mu, PJ.finger_radius, 100.0)
    np.testing.assert_allclose(np.asarray(g), ref, atol=2e-5, rtol=1e-4)
    np.testing.assert_array_equal(np.asarray(groups), np.kron(np.eye(2), np.ones((1, 10))))
    np.testing.assert_allclose(np.asarray(limits), [PJ.force_limit] * 2)


def _seal_reference(surface_depth, r=CUP.cup_radius, h=CUP.cone_height, n=8, q=3):
  """Max spring strain of the lip projected onto an analytic height field (depth below the contact)."""
  ang = 2 * np.pi * np.arange(n) / n
  verts = r * np.stack([np.cos(ang), np.sin(ang)], 1)
  frac = np.arange(q) / q
  chord = (verts[:, None] + frac[None, :, None] * (np.roll(verts, -1, 0) - verts)[:, None]).reshape(-1, 2)
  lip = np.concatenate([chord, surface_depth(chord)[:, None]], 1)  # (x, y, depth)
  ring = np.concatenate([lip, lip[:1]])
  perimeter = np.linalg.norm(np.diff(ring, axis=0), axis=1).reshape(n, q).sum(1)
  vp = lip.reshape(n, q, 3)[:, 0]
  delta = vp[:, 2].mean() - h
  apex = np.array([0.0, 0.0, min(delta, 0.0)])
  flex = np.linalg.norm(vp - np.roll(vp, -2, 0), axis=1)
  cone = np.linalg.norm(vp - apex, axis=1)
  rest = [2 * r * np.sin(np.pi / n), 2 * r * np.sin(2 * np.pi / n), np.hypot(r, h)]
  return max(np.abs(perimeter / rest[0] - 1).max(), np.abs(flex / rest[1] - 1).max(), np.abs(cone / rest[2] - 1).max())


def test_seal_on_flat_top_face_has_no_strain(box):
  s = _seal(box, SuctionGrasp(center=jnp.array([0.0, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])), CUP)
  assert bool(s.sealed) and float(s.max_strain) < 1e-3
  np.testing.assert_allclose(np.asarray(s.contact), [0, 0, 0.02], atol=3e-5)


def test_seal_strain_on_sphere_and_cylinder_matches_analytic_projection(sphere, cylinder):
  # Top of the 3 cm sphere: depth below the contact of a lip point at lateral (x, y).
  r_s = 0.03
  got = _seal(sphere, SuctionGrasp(center=jnp.array([0.0, 0.0, r_s]), approach=jnp.array([0.0, 0.0, -1.0])), CUP)
  ref = _seal_reference(lambda xy: r_s - np.sqrt(r_s**2 - (xy**2).sum(1)))
  assert bool(got.sealed) == (ref <= 0.1)
  assert abs(float(got.max_strain) - ref) < 0.01  # the mesh is a polyhedral sphere
  # Side of the 2.5 cm cylinder (axis z), approached along -x: depth depends on the lateral y only.
  r_c = 0.025
  got = _seal(cylinder, SuctionGrasp(center=jnp.array([r_c, 0.0, 0.0]), approach=jnp.array([-1.0, 0.0, 0.0])),
              CUP)
  # tangent_basis(-x) gives b1 = +y, b2 = n x b1 = -z: the first lip coordinate runs along y.
  ref = _seal_reference(lambda xy: r_c - np.sqrt(r_c**2 - xy[:, 0]**2))
  assert bool(got.sealed) == (ref <= 0.1)
  assert abs(float(got.max_strain) - ref) < 0.01


def test_no_seal_at_an_edge_or_across_a_hole(box, box_with_hole):
  edge = _seal(box, SuctionGrasp(center=jnp.array([0.037, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])), CUP)
  assert not bool(edge.sealed) and not bool(edge.lip_hits)
  hole = _seal(box_with_hole, SuctionGrasp(center=jnp.array([0.0, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])),
               CUP)
  assert not bool(hole.sealed) and not bool(hole.contact_found)
  # Off the hole by more than the cup radius plus the hole radius, the top face seals again.
  away = _seal(box_with_hole, SuctionGrasp(center=jnp.array([0.025, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])),
               CUP)
  assert bool(away.sealed)
  # Lip around the hole with the centre on material: the inner rays fall into the hole.
  rim = _seal(box_with_hole, SuctionGrasp(center=jnp.array([0.0085, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])),
              CUP)
  assert bool(rim.contact_found) and not bool(rim.sealed)


@jax.jit
def _suction_residual(p, v, com, w_ext, mu, s):
  wrenches, groups, limits, vacuum = suction_wrenches(p, v, com, mu, CUP, s)
  target = vacuum - jnp.concatenate([w_ext[:3], s * w_ext[3:]])
  return wrench_residual(wrenches, target, groups, limits)


def test_suction_wrench_set_matches_the_spec_inequalities_with_cvxopt():
  """Our cone-generator form vs. the spec's 11 linear inequalities on (f, tau), solved by cvxopt."""
  import cvxopt  # the test extra installs it: a missing reference must fail, not skip
  cvxopt.solvers.options["show_progress"] = False
  rng = np.random.default_rng(3)
  r, V, mu, s = CUP.cup_radius, CUP.vacuum_force, 0.8, 100.0
  T = np.pi * r * CUP.elastic_limit / np.sqrt(2)
  agree = feasible = 0
  trials = 60
  for _ in range(trials):
    v = rng.normal(size=3)
    v /= np.linalg.norm(v)
    p = rng.uniform(-0.02, 0.02, 3)
    com = p + rng.uniform(0.005, 0.03) * v + rng.uniform(-0.004, 0.004, 3)
    pull = v + rng.uniform(0.0, 0.8) * rng.normal(size=3)  # mostly pulling the object off the cup
    w_ext = np.concatenate([rng.uniform(0.5, 12.0) * pull / np.linalg.norm(pull), 0.005 * rng.normal(size=3)])
    ours = float(_suction_residual(jnp.asarray(p, jnp.float32), jnp.asarray(v, jnp.float32),
                                   jnp.asarray(com, jnp.float32), jnp.asarray(w_ext, jnp.float32), mu, s))
    # Reference: variables (f, tau) in the contact frame, object wrench = A (f, tau); f_z + V >= 0 etc.
    from dexjax.geometry.transforms import tangent_basis
    x, y = (np.asarray(b) for b in tangent_basis(jnp.asarray(v, jnp.float32)))
    R = np.stack([x, y, v], 1)
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, :3] = s * np.cross(p - com, R.T).T
    A[3:, 3:] = s * R
    b = -np.concatenate([w_ext[:3], s * w_ext[3:]])  # (f, tau) is the net cup wrench, vacuum included
    k3, k2 = np.sqrt(3), np.sqrt(2)
    G = []
    h = []
    for sg in (1, -1):
      G += [[sg * k3, 0, -mu, 0, 0, 0], [0, sg * k3, -mu, 0, 0, 0], [0, 0, -mu * r, 0, 0, sg * k3],
            [0, 0, 0, sg * k2, 0, 0], [0, 0, 0, 0, sg * k2, 0]]
      h += [mu * V, mu * V, mu * r * V, np.pi * r * CUP.elastic_limit, np.pi * r * CUP.elastic_limit]
    G.append([0, 0, -1, 0, 0, 0])
    h.append(V)
    sol = cvxopt.solvers.qp(cvxopt.matrix(A.T @ A), cvxopt.matrix(-A.T @ b), cvxopt.matrix(np.array(G, float)),
                            cvxopt.matrix(np.array(h, float)))
    z = np.array(sol["x"]).ravel()
    ref = np.linalg.norm(A @ z - b)
    assert T > 0
    agree += (ours <= 1e-3) == (ref <= 1e-3)
    feasible += ref <= 1e-3
    # Our residual relaxes the elastic limit into the objective (excess paid in the units of the torque it
    # buys): zero exactly when the constrained residual is zero, otherwise between ref / 2 and ref (an
    # unresisted torque can be split between excess and deficit, which at best divides the norm by sqrt 2
    # per active limit).
    assert ref / 2 - 1e-4 <= ours <= ref + 1e-4
  assert agree == trials
  assert 0.2 * trials < feasible < 0.8 * trials


def test_ring_limit_excess_is_zero_exactly_on_the_wrench_set_of_the_labels():
  """Wrenches generated as the labels' suction-ring set generates them (non-negative weights on the 8 friction /
  torsion cone generators (+-mu/sqrt3, +-mu/sqrt3, 1, +-mu r/sqrt3) and elastic torques within pi r kappa /
  sqrt 2; minus the vacuum pull along z_c) are within every limit; moving one component 5 % past its bound breaks
  exactly that limit (`dexjax.contacts.ring_limit_excess`, the physics judge's check)."""
  from dexjax.contacts import RING_LIMITS, ring_limit_excess  # pylint: disable=g-import-not-at-top
  rng = np.random.default_rng(7)
  r, V, mu = float(CUP.cup_radius), float(CUP.vacuum_force), 0.7
  bend = np.pi * r * float(CUP.elastic_limit) / np.sqrt(2)
  signs = np.array([[sx, sy, st] for sx in (1, -1) for sy in (1, -1) for st in (1, -1)], np.float64)
  for _ in range(200):
    w = rng.exponential(size=8) * rng.uniform(0.1, 10.0) / 8
    generators = np.stack([signs[:, 0] * mu / np.sqrt(3), signs[:, 1] * mu / np.sqrt(3), np.ones(8)], 1)
    force = (w[:, None] * generators).sum(0)
    torsion = float((w * signs[:, 2] * mu * r / np.sqrt(3)).sum())
    wrench = np.array([force[0], force[1], force[2] - V, *rng.uniform(-bend, bend, 2), torsion])
    assert not ring_limit_excess(wrench, mu, CUP).any()
    n = force[2]
    for name, index, bound in (('friction_x', 0, mu * n / np.sqrt(3)), ('torsion', 5, mu * r * n / np.sqrt(3)),
                               ('bending_y', 4, bend)):
      pushed = wrench.copy()
      pushed[index] = 1.05 * bound
      excess = dict(zip(RING_LIMITS, ring_limit_excess(pushed, mu, CUP)))
      assert excess[name] == pytest.approx(0.05 * bound, rel=1e-6)
      assert sum(v > 0 for v in excess.values()) == 1
