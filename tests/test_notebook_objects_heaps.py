"""``notebooks/objects_heaps.ipynb`` in a real Jupyter kernel, with few objects and heaps."""

from __future__ import annotations

import numpy as np

OBJECTS_PER_LEVEL = 3
NUM_HEAPS = 2
VALUES = {
    "solidity": "solidity",
    "report": "report.to_json()",
    "loaded": "{o.name: (o.mesh.body_count, o.mesh.is_watertight, float(o.mesh.volume)) for o in report.loaded}",
    "cover_scale_1": "(cover.mesh.extents, [type(w).__name__ for w in cover.warnings])",
    "cover_mm": "(cover_mm.mesh.extents, list(cover_mm.warnings))",
    "prepared": "[p.name for p in prepared]",
    "rejected": "[(r.file, r.reason) for r in rejected]",
    "num_objects": "np.asarray(states.num_objects)",
    "object_ids": "np.asarray(states.object_ids)",
    "result": "{k: getattr(result, k) for k in ('mask', 'centers', 'initial_poses', 'left_bin', 'never_settled', "
              "'settled', 'diverged', 'steps')}",
    "summary": "result.summary()",
    "rows": "[(row.label, row.result.summary()) for row in rows]",
    "image": "{'depth': depth, 'slots': slots, 'empty': empty.depth, 'height': height, 'heap': heap}",
}


def test_objects_heaps_notebook(run_notebook):
  """The folder report (repairs, warning, rejections naming the files), the millimetre scale, the object set,
  settled heaps at rest inside the bin, the heap sheet's rows and a depth image whose objects lie above the floor."""
  run = run_notebook("objects_heaps.ipynb", {"OBJECTS_PER_LEVEL": OBJECTS_PER_LEVEL, "SHEET_COLUMNS": 3,
                                             "NUM_HEAPS": NUM_HEAPS, "HEAPS_PER_LEVEL": 1}, VALUES)
  v = run.values

  # Procedural levels: level 1 is convex, level 3 much less solid.
  solidity = v["solidity"]
  assert [len(solidity[level]) for level in (1, 2, 3)] == [OBJECTS_PER_LEVEL] * 3
  assert min(solidity[1]) > 0.99 and np.mean(solidity[3]) < np.mean(solidity[1]) - 0.2

  # The folder: three files load (one with a warning), three are rejected, each rejection naming its file.
  report = v["report"]
  assert report["loaded"] == ["bracket", "can_flipped", "can_no_lid"]
  reasons = {r["file"]: r["reason"] for r in report["rejected"]}
  assert set(reasons) == {"broken.obj", "label_sheet.stl", "notes.txt"}
  assert "NaN" in reasons["broken.obj"] and "zero volume" in reasons["label_sheet.stl"]
  assert "unsupported extension .txt" in reasons["notes.txt"]
  assert [w["name"] for w in report["warnings"]] == ["can_no_lid"]
  assert "can_no_lid.stl" in report["warnings"][0]["warning"] and "32 open edges" in report["warnings"][0]["warning"]
  loaded = v["loaded"]
  parts, watertight, volume = loaded["bracket"]  # two overlapping boxes -> their exact union
  assert parts == 1 and watertight and abs(volume - (0.08 * 0.03 * 0.008 + 0.008 * 0.028 * 0.054)) < 1e-8
  can = 12 * 0.03**2 * np.sin(2 * np.pi / 24) * 0.1  # 24-sided prism, re-oriented outward: positive volume
  assert loaded["can_flipped"][:2] == (1, True) and abs(loaded["can_flipped"][2] - can) < 1e-9
  open_can = 16 * 0.035**2 * np.sin(2 * np.pi / 32) * 0.09  # the rebuilt solid closes the lid
  assert loaded["can_no_lid"][1] and abs(loaded["can_no_lid"][2] / open_can - 1) < 0.02

  # Millimetres: a ScaleWarning at scale 1, 9 x 6 x 3 cm at scale 0.001.
  extents, warned = v["cover_scale_1"]
  assert np.allclose(extents, [90, 60, 30]) and warned == ["ScaleWarning"]
  extents, warned = v["cover_mm"]
  assert np.allclose(extents, [0.09, 0.06, 0.03]) and warned == []

  # The object set: every procedural object, the three loaded files and the cover; the three bad files rejected.
  prepared = v["prepared"]
  assert prepared == ([f"procedural:L{level}/{i}" for level in (1, 2, 3) for i in range(OBJECTS_PER_LEVEL)]
                      + ["my_objects/bracket", "my_objects/can_flipped", "my_objects/can_no_lid", "cad_mm/cover"])
  assert sorted(f.rsplit("/", 1)[-1] for f, _ in v["rejected"]) == ["broken.obj", "label_sheet.stl", "notes.txt"]

  # Settled heaps: counts match the sampled states; every object rests inside the bin, below its drop height.
  counts, ids, r = v["num_objects"], v["object_ids"], v["result"]
  mask = r["mask"]
  assert counts.shape == (NUM_HEAPS,) and np.all((counts >= 3) & (counts <= 10))
  assert np.array_equal(mask.sum(axis=1), counts) and np.array_equal(ids >= 0, mask)
  assert np.all(ids[mask] < len(prepared))
  assert v["summary"]["objects"] == counts.sum() and v["summary"]["heaps"] == NUM_HEAPS
  assert r["settled"].all() and not r["diverged"].any() and not r["never_settled"].any() and not r["left_bin"].any()
  assert np.all((r["steps"] > 0) & (r["steps"] <= 500))
  c = r["centers"][mask]
  assert np.all(np.abs(c[:, :2]) < 0.2) and np.all(c[:, 2] > 0.0)  # within the inner walls, above the floor
  assert np.all(c[:, 2] < r["initial_poses"][..., 2][mask] - 0.02)  # fell from the drop height (objects may stack)

  # The heap sheet: one row per level and the mixed set, each of one settled heap.
  rows = v["rows"]
  assert [label for label, _ in rows] == ["level 1", "level 2", "level 3", "mixed set"]
  assert all(s["heaps"] == 1 and s["settled_heaps"] == 1 and s["left_bin"] == 0 for _, s in rows)

  # The depth image of the largest heap: object pixels are its slots and lie nearer than the empty bin's floor.
  image = v["image"]
  depth, slots, empty, height = image["depth"], image["slots"], image["empty"], image["height"]
  assert depth.shape == slots.shape == (500, 500) and image["heap"] == int(np.argmax(counts))
  objects = slots >= 0
  assert objects.mean() > 0.005 and set(np.unique(slots[objects])) <= set(np.flatnonzero(mask[image["heap"]]))
  assert np.all(depth[objects] <= empty[objects] + 1e-4) and np.median(empty[objects] - depth[objects]) > 0.005
  assert np.all(np.isfinite(depth)) and np.median(np.abs(height[slots == -1])) < 0.001  # the floor is z = 0
  assert np.median(height[objects]) > 0.005

  assert run.images() == 6  # contact sheet, solidity, your meshes, settling statistics, heap sheet, depth image
  assert "rejected broken.obj: 1 vertices have NaN" in run.stdout()
