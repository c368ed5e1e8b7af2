"""The Dex-Net 4.0 data-collection policy tau (seed, "Data Collection Policy"), for one image and one gripper.

    tau(u | x, y) = Omega(x)          with probability epsilon
                    Unif(U_g(y))      otherwise

U_g(y) is the image's candidate set of the gripper (`dexjax.sampling` image samplers) and Omega the algorithmic
supervisor (`dexjax.generate.supervisor`). We label ``actions_per_gripper`` actions per image and gripper: each
action independently comes from the supervisor with probability ``epsilon``, otherwise from the candidates.
Candidate actions of one image are drawn uniformly *without* replacement (distinct rows; with replacement
would label the same grasp twice), supervisor actions uniformly with replacement among its eligible grasps.
When the supervisor has no eligible grasp in this image, the action falls back to a candidate; when the
candidates run out, the action is dropped (``ok`` False).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

CANDIDATE, SUPERVISOR, POLICY = 0, 1, 2
"""A row's ``policy`` code: a uniform candidate of U_g(y), the supervisor Omega, or a grasp a learned policy
scored (on-policy synthesis, `dexjax.generate.on_policy`)."""


@struct.dataclass
class PolicyParams:
  """Parameters of the collection policy.

  Attributes:
    epsilon: probability that an action comes from the supervisor Omega (seed: 1 %).
    actions_per_gripper: static, actions labelled per image and gripper (equal numbers for both grippers).
    floor_clearance: candidates are sampled on points above the bottom of the bin: world z above this, metres,
      inside the bin's inner footprint (`dexjax.generate.pickable_mask`).
    top_k: static; with candidates a learned policy scored (on-policy synthesis), its ``top_k`` highest-scored
      candidates are taken first, the other candidate actions uniformly among the rest (0: all uniformly). The
      seed's tau has no such term: its candidates carry no score.
  """

  epsilon: float = 0.01
  actions_per_gripper: int = struct.field(pytree_node=False, default=50)
  floor_clearance: float = 0.005
  top_k: int = struct.field(pytree_node=False, default=0)

  def validate(self) -> PolicyParams:
    """Checks the fields; raises ValueError naming the field and the expected value."""
    if not 0.0 <= float(self.epsilon) <= 1.0:
      raise ValueError(f'PolicyParams.epsilon: expected a probability in [0, 1], got {self.epsilon!r}')
    if isinstance(self.actions_per_gripper, bool) or int(self.actions_per_gripper) < 1:
      raise ValueError(f'PolicyParams.actions_per_gripper: expected an integer >= 1, got {self.actions_per_gripper!r}')
    if isinstance(self.top_k, bool) or not 0 <= int(self.top_k) <= int(self.actions_per_gripper):
      raise ValueError(f'PolicyParams.top_k: expected an integer in [0, actions_per_gripper = '
                       f'{self.actions_per_gripper}], got {self.top_k!r}')
    return self


_LEAD = 1e4  # a led candidate's rank score: above any Gumbel draw (float32 draws stay below ~90)


def _ranked(key: jax.Array, eligible: jax.Array, k: int, priority: jax.Array | None = None,
            top: int = 0) -> tuple[jax.Array, jax.Array]:
  """``k`` distinct indices drawn uniformly without replacement among ``eligible`` (N,) (Gumbel top-k),
  eligible ones first; with ``priority`` (N,), the ``top`` eligible ones of highest priority come first (in order
  of priority). Returns (indices (k,) int32, ok (k,) bool)."""
  scores = jnp.where(eligible, jax.random.gumbel(key, eligible.shape), -jnp.inf)
  if priority is not None and top > 0:
    ranked = jnp.where(eligible, priority, -jnp.inf)
    _, best = jax.lax.top_k(ranked, top)
    lead = jnp.full(eligible.shape, -1, jnp.int32).at[best].set(jnp.arange(top, 0, -1, dtype=jnp.int32))
    lead = jnp.where(eligible & (lead > 0), lead, 0)
    scores = jnp.where(lead > 0, _LEAD * lead.astype(scores.dtype), scores)
  values, idx = jax.lax.top_k(scores, k)
  return idx.astype(jnp.int32), jnp.isfinite(values)



def supervisor_draws(key: jax.Array, params: PolicyParams = PolicyParams()) -> jax.Array:
  """(A,) bool, the actions for which tau (with this ``key``) wants the supervisor (probability epsilon each);
  the same draws `collection_actions` makes with the same key."""
  k_mix = jax.random.split(key, 3)[0]
  return jax.random.uniform(k_mix, (params.actions_per_gripper,)) < params.epsilon


def collection_actions(key: jax.Array, candidate_valid: jax.Array, supervisor_eligible: jax.Array,
                       params: PolicyParams = PolicyParams(),
                       priority: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Which actions tau takes in one image, for one gripper.

  Args:
    key: PRNG key.
    candidate_valid: (N,) bool, the valid candidates of U_g(y).
    supervisor_eligible: (S,) bool, the supervisor's eligible grasps in this image (S may be 0).
    params: `PolicyParams`; A = ``params.actions_per_gripper`` (must be <= N).
    priority: (N,) the candidates' scores (a learned policy's): the ``params.top_k`` highest come first; None
      (the seed's tau): every candidate action uniform.

  Returns:
    source: (A,) int32, `CANDIDATE` (0) or `SUPERVISOR` (1) per action.
    index: (A,) int32 index into the candidates or into the supervisor's grasps, by ``source``.
    ok: (A,) bool, the action exists (False only when the candidates ran out).
  """
  a = params.actions_per_gripper
  if a > candidate_valid.shape[0]:
    raise ValueError(f'PolicyParams.actions_per_gripper: expected at most the candidate budget '
                     f'{candidate_valid.shape[0]}, got {a}')
  _, k_cand, k_sup = jax.random.split(key, 3)
  has_supervisor = jnp.any(supervisor_eligible) if supervisor_eligible.shape[0] else jnp.bool_(False)
  use_sup = supervisor_draws(key, params) & has_supervisor
  cand_idx, cand_ok = _ranked(k_cand, candidate_valid, a, priority, params.top_k)
  order = jnp.cumsum(~use_sup) - 1  # the j-th candidate action takes the j-th ranked candidate
  cand_for_action = cand_idx[jnp.clip(order, 0, a - 1)]
  cand_ok_for_action = cand_ok[jnp.clip(order, 0, a - 1)]
  if supervisor_eligible.shape[0]:
    logits = jnp.where(supervisor_eligible, 0.0, -jnp.inf)
    sup_idx = jax.random.categorical(k_sup, jnp.where(has_supervisor, logits, 0.0), shape=(a,)).astype(jnp.int32)
  else:
    sup_idx = jnp.zeros((a,), jnp.int32)
  source = jnp.where(use_sup, SUPERVISOR, CANDIDATE).astype(jnp.int32)
  index = jnp.where(use_sup, sup_idx, cand_for_action)
  ok = use_sup | cand_ok_for_action
  return source, index, ok


__all__ = ['CANDIDATE', 'POLICY', 'SUPERVISOR', 'PolicyParams', 'collection_actions', 'supervisor_draws']
