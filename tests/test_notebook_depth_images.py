"""``notebooks/depth_images.ipynb`` in a real Jupyter kernel, with few cameras, built-in objects and a smaller camera."""

from __future__ import annotations

import os

import numpy as np

SMALL = {
    "OBJECTS": ["builtin:cube", "builtin:box", "builtin:cylinder"],
    "NUM_CAMERAS": 64,
    "NUM_VIEWS": 2,
    "IMAGE_WIDTH": 320,    # not the notebook's 640 x 480: the loaded file must drive the rendered size
    "IMAGE_HEIGHT": 240,
    "FOCAL": 287.9,
    "CAMERA_HEIGHT": 0.7,  # not the default 0.8: the depths below must follow the file's pose
    "DROPOUT_RATE": 0.05,
    "NUM_GAMMA_DRAWS": 400,
}

VALUES = {name: name for name in (
    "focal", "cx", "cy", "distance", "tilt_deg", "azimuth_deg", "centre", "height", "origin_uv", "centre_depth",
    "ring_mismatch", "ring_area", "errors", "distortion_warnings", "ratio", "gamma_factors", "gp_error", "dropout_fraction",
    "png_error", "png_step", "holes_kept", "preview_error", "floor_z", "ring_xy", "object_points", "workdir")}
VALUES.update({
    "dist_ranges": "{f: getattr(dist, f) for f in ('focal', 'cx', 'cy', 'radius', 'phi_deg', 'theta_deg', "
                   "'center_x', 'center_y')}",
    "view_shapes": "[im.depth.shape for im in images]",
    "user_shape": "user_image.depth.shape",
    "user_size": "(user_k.width, user_k.height)",
    "empty_range": "(float(np.nanmin(top_empty.depth)), float(np.nanmax(top_empty.depth)))",
    "ring_count": "int(ring_pixels.sum())",
    "deproject_error": "float(np.nanmax(np.abs(points - by_hand)))",
    "noisy_invalid": "float(np.mean(noisy_mask == INVALID_LABEL))",
    "readback_shape": "readback.shape",
})


def test_depth_images_notebook(run_notebook):
  """Sampled cameras lie in the Dex-Net 4.0 ranges; the CameraInfo file sets the rendered size; a straight-down posed
  camera sees the floor at its height and the wall tops where projection predicts; noise statistics match the
  settings; the 16-bit PNG round trip is within half a step; bad files name the file and the field."""
  run = run_notebook("depth_images.ipynb", SMALL, VALUES)
  v = run.values
  eps = 1e-4

  # The camera distribution, recovered from the poses alone.
  r = v["dist_ranges"]
  for name, field in (("focal", "focal"), ("cx", "cx"), ("cy", "cy"), ("distance", "radius"), ("tilt_deg", "phi_deg"),
                      ("azimuth_deg", "theta_deg")):
    values, (low, high) = np.asarray(v[name]), r[field]
    assert values.shape == (64,), name
    assert values.min() >= low - eps * max(1, abs(low)) and values.max() <= high + eps * max(1, abs(high)), (name, low, high)
    assert values.max() - values.min() > 0.5 * (high - low), name  # spread over the range, not one value
  assert np.all(np.abs(v["centre"][:, 2]) < 1e-5)  # the optical axis meets the floor at the look-at point
  assert np.all(np.abs(v["centre"][:, 0]) <= 0.05 + 1e-4) and np.all(np.abs(v["centre"][:, 1]) <= 0.05 + 1e-4)
  assert np.allclose(v["height"], v["distance"] * np.cos(np.radians(v["tilt_deg"])), atol=1e-5)
  assert v["view_shapes"] == [(500, 500)] * 2

  # The user's CameraInfo drives the rendered size; the posed camera's exact geometry.
  assert v["user_size"] == (320, 240) and v["user_shape"] == (240, 320)
  assert np.allclose(v["origin_uv"], [159.5, 119.5], atol=1e-3)  # the bin centre projects on the principal point
  assert abs(v["centre_depth"] - 0.7) < 1e-4
  low, high = v["empty_range"]
  assert abs(low - 0.6) < 1e-4 and abs(high - 0.7) < 1e-4  # wall tops 0.1 m above the floor; nothing farther
  # The pixels rendered at the wall tops' depth are those whose ray crosses z = 0.1 m on the 0.40-0.42 m ring.
  assert v["ring_count"] > 3000 and v["ring_mismatch"] <= 0.005 * v["ring_count"], (v["ring_count"], v["ring_mismatch"])
  assert abs(v["ring_area"] - 0.0164 * (287.9 / 0.6) ** 2) < 1e-3 * v["ring_area"]
  assert abs(v["ring_count"] / v["ring_area"] - 1) < 0.25  # the ring is ~5 px wide: whole columns, not area
  assert np.abs(v["floor_z"]).max() < 1e-3  # deprojected floor on z = 0
  assert v["ring_xy"].min() > 0.2 - 2e-3 and v["ring_xy"].max() < 0.21 + 2e-3  # wall tops between 0.20 and 0.21 m
  assert v["deproject_error"] < 1e-5
  objects = v["object_points"]
  assert len(objects) > 100 and objects[:, 2].min() > -2e-3  # nothing below the floor
  assert np.mean(np.all(np.abs(objects[:, :2]) < 0.2 + 1e-3, axis=1)) > 0.99  # inside the bin's walls

  # Bad files: every message names the file and the field.
  workdir = v["workdir"]
  expected = {"negative focal length": ("negative_fx.json", "fx"), "width as a float": ("float_width.json", "width"),
              "missing height": ("no_height.json", "height"), "uncalibrated CameraInfo": ("uncalibrated.yaml", "k[0] (fx)"),
              "K with 6 numbers": ("short_k.yaml", "k:"), "mirrored rotation": ("mirrored.json", "rotation"),
              "position of 2 numbers": ("flat_position.json", "position"),
              "camera looking up": ("looking_up.json", "rotation")}
  assert set(v["errors"]) == set(expected)
  for label, (file_name, field) in expected.items():
    message = v["errors"][label]
    assert message is not None, label
    assert file_name in message and f": {field}" in message, (label, message)
    if label != "camera looking up":
      assert message.startswith(os.path.join(workdir, file_name)), (label, message)
  assert "-1" in v["errors"]["mirrored rotation"] and "640" not in v["errors"]["width as a float"]
  assert len(v["distortion_warnings"]) == 1 and "distorted.yaml: d:" in v["distortion_warnings"][0]

  # Noise against its settings (the image is 500 x 500 = 250,000 pixels).
  assert np.ptp(v["ratio"]) < 1e-5 and abs(v["ratio"].mean() - 1) < 0.15  # one Gamma factor per image
  factors = v["gamma_factors"]
  assert factors.shape == (400,) and abs(factors.mean() - 1) < 5 * 0.0316 / 20  # mean 1, 5 standard errors
  assert abs(factors.std() / (1 / np.sqrt(1000.0)) - 1) < 0.15
  assert abs(v["gp_error"].std() / 0.005 - 1) < 0.05 and abs(v["gp_error"].mean()) < 0.0005
  n = 500 * 500
  assert abs(v["dropout_fraction"] - 0.05) < 5 * np.sqrt(0.05 * 0.95 / n)
  assert abs(v["noisy_invalid"] - 0.05) < 0.005  # the mask marks the dropped pixels

  # 16-bit PNG: below half the quantisation step; holes come back as 0; the preview PNG is refused.
  assert v["png_step"] == 0.001 and v["readback_shape"] == (500, 500)
  assert v["png_error"].max() <= 0.5 * v["png_step"] + 1e-6 and v["png_error"].max() > 0.1 * v["png_step"]
  assert v["holes_kept"]
  assert "preview.png" in v["preview_error"] and "visualisation" in v["preview_error"]

  assert run.images() == 7  # distribution, heap views, your camera, noise images, profile/histograms, preview, cloud
  out = run.stdout()
  assert "64 cameras in" in out and "wall-top pixels" in out
