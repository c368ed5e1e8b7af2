"""Grasp samplers: 3-D samplers on object models, image-space samplers on depth images, grasp-centred crops."""

from dexjax.sampling.crops import crop_coordinates, grasp_crop, model_crop, sample_bilinear
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach,
                                          approach_from_angles, parallel_jaw_grasp_3d, suction_grasp_3d)
from dexjax.sampling.image_samplers import (AntipodalImageSampler, SuctionImageSampler, sample_antipodal_image_grasps,
                                            sample_suction_image_grasps)
from dexjax.sampling.object_samplers import (AntipodalSampler, antipodal, sample_antipodal_grasps,
                                             sample_suction_grasps)

__all__ = [
    "AntipodalSampler", "antipodal", "sample_antipodal_grasps", "sample_suction_grasps", "ImageParallelJawGrasp",
    "ImageSuctionGrasp", "angles_from_approach", "approach_from_angles", "parallel_jaw_grasp_3d",
    "suction_grasp_3d", "AntipodalImageSampler", "SuctionImageSampler", "sample_antipodal_image_grasps",
    "sample_suction_image_grasps", "crop_coordinates", "grasp_crop", "model_crop", "sample_bilinear",
]
