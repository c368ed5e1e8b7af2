"""Contact models: parallel-jaw soft fingers and the compliant suction ring."""

from dexjax.contacts.parallel_jaw import JawContacts, close_jaws, in_friction_cone, jaw_lines, soft_finger_wrenches
from dexjax.contacts.suction import SealResult, approach_contact, suction_seal, suction_wrenches

__all__ = ["JawContacts", "close_jaws", "in_friction_cone", "jaw_lines", "soft_finger_wrenches", "SealResult",
           "approach_contact", "suction_seal", "suction_wrenches"]
