"""Grasp samplers: 3-D samplers on object models (image-space samplers join them with the dataset work)."""

from dexjax.sampling.object_samplers import (AntipodalSampler, antipodal, sample_antipodal_grasps,
                                             sample_suction_grasps)

__all__ = ["AntipodalSampler", "antipodal", "sample_antipodal_grasps", "sample_suction_grasps"]
