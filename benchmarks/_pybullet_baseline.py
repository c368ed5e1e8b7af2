"""The seed's way of settling heaps, for `heap_throughput.py`: pybullet (Bullet), DIRECT mode, its own defaults.

Dex-Net 4.0 dropped each heap in pybullet and stepped until every object was slower than 0.005 m/s and
0.1 rad/s, or 500 time steps had passed (seed, "State Distribution"). This module does exactly that for the
heaps dexjax settles, built from the same data:

* the same convex collision hulls as dexjax's `HeapObject.hulls` (a single hull as a ``GEOM_MESH`` from its
  vertices, several as a compound ``createCollisionShapeArray`` of ``GEOM_MESH`` OBJ files holding each
  hull, written once per worker process), i.e. the same shapes MuJoCo takes the convex hull of;
* the same mass, centre of mass and inertia tensor: each body's frame is the object's principal frame at its
  centre of mass (hull vertices expressed in it), with ``localInertiaDiagonal`` = the tensor's eigenvalues;
* the same drop poses (`dexjax.sim.drop_poses`, the poses dexjax simulates, with intersecting drops raised),
  all objects released at once at rest;
* the same bin: a ground plane at z = 0 and the four wall boxes of `dexjax.sim.bin_boxes`, static;
* the heap state's per-object friction as each object's ``lateralFriction``, with the static bin and ground
  at 1.0, so an object--bin contact has exactly the object's coefficient (Bullet multiplies the two bodies'
  coefficients: an object--object contact gets mu_i mu_j, where MuJoCo/dexjax take the larger of the two);
* gravity -9.81 m/s^2 along z; the stopping rule checked after every ``stepSimulation`` on every object's
  centre-of-mass linear and angular speed (``getBaseVelocity``), capped at 500 steps;
* everything else pybullet's defaults: time step 1/240 s (500 steps = 2.08 s simulated; dexjax: 500 x 4 ms =
  2.0 s), 50 solver iterations, no sub-steps, restitution 0, no rolling or spinning friction, default contact
  ERP and collision margins.

Work is split over worker processes (``multiprocessing`` with ``spawn``), each with its own DIRECT client,
heaps handed out one at a time, so the two cores are used as dexjax's two `rollout` threads use them. Each
heap rebuilds its world (``resetSimulation``) as dexjax builds one MuJoCo model per heap. Imports no JAX.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import tempfile

import numpy as np

GRAVITY = 9.81
#: pybullet's default time step (never changed here; `engine_parameters` reports the engine's own value), s.
TIME_STEP = 1.0 / 240.0
MAX_STEPS = 500
LINEAR_TOL = 0.005
ANGULAR_TOL = 0.1


@dataclasses.dataclass(frozen=True)
class BulletObject:
  """One object in its principal frame: hulls (V_i, 3) about the centre of mass, mass kg, inertia eigenvalues
  kg m^2, and ``principal`` (3, 3), the principal axes as columns in the object frame."""

  hulls: tuple
  mass: float
  inertia_diagonal: np.ndarray
  principal: np.ndarray
  center_of_mass: np.ndarray


@dataclasses.dataclass(frozen=True)
class BulletHeap:
  """One heap: object ids (m,), centre-of-mass drop positions (m, 3), principal-frame orientations (m, 4)
  as pybullet quaternions (x, y, z, w), friction (m,). ``rolling_friction`` and ``spinning_friction`` (m)
  are None for pybullet's default (none); the sensitivity variant sets dexjax's 2 mm and 5 mm."""

  object_ids: np.ndarray
  positions: np.ndarray
  orientations: np.ndarray
  friction: np.ndarray
  rolling_friction: float | None = None
  spinning_friction: float | None = None


def bullet_objects(heap_objects) -> list[BulletObject]:
  """`BulletObject` s of dexjax `HeapObject` s (same hulls, mass, centre of mass and inertia)."""
  out = []
  for obj in heap_objects:
    eig, vec = np.linalg.eigh(obj.inertia)
    if np.linalg.det(vec) < 0:
      vec[:, 2] *= -1
    hulls = tuple((h - obj.center_of_mass) @ vec for h in obj.hulls)
    out.append(BulletObject(hulls=hulls, mass=float(obj.mass), inertia_diagonal=eig, principal=vec,
                            center_of_mass=np.asarray(obj.center_of_mass)))
  return out


def bullet_heaps(objects: list[BulletObject], positions: np.ndarray, quaternions: np.ndarray, object_ids: np.ndarray,
                 friction: np.ndarray, mask: np.ndarray) -> list[BulletHeap]:
  """Heaps from dexjax drop poses: positions (B, P, 3) of the object frames' origins and quaternions (B, P, 4)
  (w, x, y, z), as `dexjax.sim.drop_poses` returns them, with the states' ids, friction and mask (B, P)."""
  from scipy.spatial.transform import Rotation  # pylint: disable=g-import-not-at-top,import-outside-toplevel
  heaps = []
  for b in range(len(mask)):
    slots = np.flatnonzero(mask[b])
    ids = np.asarray(object_ids[b])[slots].astype(int)
    pos, orient = [], []
    for slot, i in zip(slots, ids):
      q = quaternions[b, slot] / np.linalg.norm(quaternions[b, slot])
      rot = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
      pos.append(positions[b, slot] + rot @ objects[i].center_of_mass)
      orient.append(Rotation.from_matrix(rot @ objects[i].principal).as_quat())
    heaps.append(BulletHeap(object_ids=ids, positions=np.array(pos), orientations=np.array(orient),
                            friction=np.asarray(friction[b])[slots].astype(float)))
  return heaps


_WORKER: dict = {}


def _write_obj(path: str, vertices: np.ndarray) -> None:
  import trimesh  # pylint: disable=g-import-not-at-top,import-outside-toplevel
  trimesh.convex.convex_hull(vertices).export(path)


def _init(objects: list[BulletObject], walls: list[tuple[np.ndarray, np.ndarray]]) -> None:
  """Worker start: one DIRECT client, OBJ files of the multi-hull objects' pieces."""
  import pybullet as p  # pylint: disable=g-import-not-at-top,import-outside-toplevel
  client = p.connect(p.DIRECT)
  tmp = tempfile.mkdtemp(prefix='dexjax_pybullet_')
  files = {}
  for i, obj in enumerate(objects):
    if len(obj.hulls) > 1:
      files[i] = []
      for j, hull in enumerate(obj.hulls):
        path = os.path.join(tmp, f'obj{i}_hull{j}.obj')
        _write_obj(path, hull)
        files[i].append(path)
  _WORKER.update(p=p, client=client, objects=objects, walls=walls, files=files, tmp=tmp)


def engine_parameters() -> dict:
  """pybullet's default engine parameters (a fresh DIRECT client), for the report."""
  import pybullet as p  # pylint: disable=g-import-not-at-top,import-outside-toplevel
  client = p.connect(p.DIRECT)
  try:
    params = p.getPhysicsEngineParameters(physicsClientId=client)
  finally:
    p.disconnect(client)
  return {k: (float(v) if isinstance(v, float) else v) for k, v in params.items()}


def settle_heap(heap: BulletHeap) -> dict:
  """Drops and settles one heap in this worker's client; steps, settled, final centres of mass (m, 3)."""
  p, c, objects = _WORKER['p'], _WORKER['client'], _WORKER['objects']
  p.resetSimulation(physicsClientId=c)
  p.setGravity(0, 0, -GRAVITY, physicsClientId=c)
  statics = [p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c), physicsClientId=c)]
  for centre, half in _WORKER['walls']:
    shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half), physicsClientId=c)
    statics.append(p.createMultiBody(0, shape, basePosition=list(centre), physicsClientId=c))
  for body in statics:
    p.changeDynamics(body, -1, lateralFriction=1.0, physicsClientId=c)
  bodies = []
  for i, pos, orient, mu in zip(heap.object_ids, heap.positions, heap.orientations, heap.friction):
    obj = objects[i]
    if i in _WORKER['files']:
      paths = _WORKER['files'][i]
      shape = p.createCollisionShapeArray([p.GEOM_MESH] * len(paths), fileNames=paths, physicsClientId=c)
    else:
      shape = p.createCollisionShape(p.GEOM_MESH, vertices=obj.hulls[0].tolist(), physicsClientId=c)
    body = p.createMultiBody(obj.mass, shape, basePosition=list(pos), baseOrientation=list(orient),
                             physicsClientId=c)
    p.changeDynamics(body, -1, lateralFriction=float(mu), localInertiaDiagonal=list(obj.inertia_diagonal),
                     physicsClientId=c)
    if heap.rolling_friction is not None:  # Bullet combines rf_a mu_b + mu_a rf_b: with the bin's 1.0, rf
      p.changeDynamics(body, -1, rollingFriction=heap.rolling_friction, spinningFriction=heap.spinning_friction,
                       physicsClientId=c)
    bodies.append(body)
  steps, settled = MAX_STEPS, False
  for step in range(1, MAX_STEPS + 1):
    p.stepSimulation(physicsClientId=c)
    rest = True
    for body in bodies:
      lin, ang = p.getBaseVelocity(body, physicsClientId=c)
      if (lin[0] ** 2 + lin[1] ** 2 + lin[2] ** 2 >= LINEAR_TOL ** 2
          or ang[0] ** 2 + ang[1] ** 2 + ang[2] ** 2 >= ANGULAR_TOL ** 2):
        rest = False
        break
    if rest:
      steps, settled = step, True
      break
  centers = np.array([p.getBasePositionAndOrientation(b, physicsClientId=c)[0] for b in bodies])
  return {'steps': steps, 'settled': settled, 'centers': centers}


class BulletPool:
  """``processes`` worker processes (``spawn``), each with its own pybullet DIRECT client."""

  def __init__(self, objects: list[BulletObject], walls: list[tuple[np.ndarray, np.ndarray]], processes: int):
    ctx = multiprocessing.get_context('spawn')
    self.processes = processes
    self.pool = ctx.Pool(processes, initializer=_init, initargs=(objects, walls))

  def settle(self, heaps: list[BulletHeap]) -> list[dict]:
    """Settles ``heaps``, handed out one at a time to the workers; results in order."""
    return self.pool.map(settle_heap, heaps, chunksize=1)

  def close(self) -> None:
    self.pool.close()
    self.pool.join()


def summary(results: list[dict], bin_inner_size: tuple[float, float]) -> dict:
  """Settled fraction, steps and objects that left the bin (centre of mass outside the inner box or below
  z = 0, as `dexjax.sim.settle` flags them)."""
  hx, hy = 0.5 * bin_inner_size[0], 0.5 * bin_inner_size[1]
  centers = np.concatenate([r['centers'] for r in results])
  left = ((np.abs(centers[:, 0]) > hx) | (np.abs(centers[:, 1]) > hy) | (centers[:, 2] < 0.0)
          | ~np.all(np.isfinite(centers), axis=1))
  return {'settled_fraction': float(np.mean([r['settled'] for r in results])),
          'mean_steps': float(np.mean([r['steps'] for r in results])),
          'objects': int(len(centers)), 'left_bin': int(left.sum()), 'left_bin_fraction': float(left.mean()),
          'mean_final_com_height_m': float(np.mean(centers[:, 2]))}
