"""Contact models: parallel-jaw soft fingers and the compliant suction ring."""

from dexjax.contacts.parallel_jaw import JawContacts, close_jaws, in_friction_cone, jaw_lines, soft_finger_wrenches
from dexjax.contacts.suction import (RING_LIMITS, SealResult, approach_contact, ring_frame, ring_limit_excess,
                                     suction_seal, suction_wrenches)

__all__ = ["JawContacts", "close_jaws", "in_friction_cone", "jaw_lines", "soft_finger_wrenches", "SealResult",
           "approach_contact", "RING_LIMITS", "ring_frame", "ring_limit_excess", "suction_seal", "suction_wrenches"]
