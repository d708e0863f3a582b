#!/usr/bin/python3
"""Third-party readers (issue 19, item 6): Open3D (Debian's python3-open3d)
opens a scan's fused.ply, mesh.ply, mesh.obj and mesh.glb, and what it finds
(point, vertex and triangle counts; axis-aligned bounds) is what report.json
says. The GLB holds metres with +Y up (glb.h): its bounds are turned back to
the turntable frame in mm before the comparison.

    /usr/bin/python3 third_party_readers.py DIR

Exit 0 pass, 1 fail, 77 skipped (no Open3D or NumPy), 2 usage.
"""
import json
import os
import sys

try:
    import numpy as np
    import open3d as o3d
except ImportError as e:  # Debian's modules load only with /usr/bin/python3
    print(f"SKIP: open3d/numpy not importable ({e}); apt-get install python3-open3d")
    sys.exit(77)

if len(sys.argv) != 2:
    print(__doc__)
    sys.exit(2)
folder = sys.argv[1]
with open(os.path.join(folder, "report.json"), encoding="utf-8") as f:
    report = json.load(f)
failures = []


def expect(ok, what):
    if not ok:
        failures.append(what)


def expect_bounds(name, lo, hi, bounds, tol_mm):
    for k in range(3):
        d = max(abs(lo[k] - bounds["min"][k]), abs(hi[k] - bounds["max"][k]))
        expect(d <= tol_mm, f"{name}: axis {k} bounds {lo[k]:.4f}..{hi[k]:.4f} mm vs "
               f"report.json {bounds['min'][k]:.4f}..{bounds['max'][k]:.4f} mm "
               f"(off by {d:.2g} mm, tolerance {tol_mm} mm)")


# fused.ply: binary PLY, float mm; bounds exact but for the JSON's rounding.
cloud = o3d.io.read_point_cloud(os.path.join(folder, "fused.ply"))
n = len(cloud.points)
print(f"fused.ply: {n} points, colours {cloud.has_colors()}, normals {cloud.has_normals()}")
expect(n == report["fused_points"], f"fused.ply: {n} points, report.json {report['fused_points']}")
expect(cloud.has_colors() and cloud.has_normals(), "fused.ply: colours and normals")
expect_bounds("fused.ply", cloud.get_min_bound(), cloud.get_max_bound(),
              report["fused_bounds_mm"], 1e-3)

mesh_report = report["mesh"]
# (file, tolerance mm, to the turntable frame in mm)
readers = [
    ("mesh.ply", 1e-3, lambda v: v),
    # OBJ is text: the writer's precision bounds the error.
    ("mesh.obj", 1e-2, lambda v: v),
    # glTF: metres, +Y up: turntable (x, y, z) = 1000 · (x, −z, y).
    ("mesh.glb", 1e-3, lambda v: 1000.0 * np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)),
]
for name, tol, to_turntable in readers:
    mesh = o3d.io.read_triangle_mesh(os.path.join(folder, name))
    v = np.asarray(mesh.vertices, dtype=np.float64)
    t = len(mesh.triangles)
    print(f"{name}: {len(v)} vertices, {t} triangles, colours {mesh.has_vertex_colors()}")
    expect(len(v) == mesh_report["vertices"],
           f"{name}: {len(v)} vertices, report.json {mesh_report['vertices']}")
    expect(t == mesh_report["faces"], f"{name}: {t} triangles, report.json {mesh_report['faces']}")
    if len(v):
        p = to_turntable(v)
        expect_bounds(name, p.min(axis=0), p.max(axis=0), mesh_report["bounds_mm"], tol)
    if name != "mesh.obj":  # OBJ has no standard vertex colours
        expect(mesh.has_vertex_colors(), f"{name}: vertex colours")

if failures:
    print("FAIL:\n  " + "\n  ".join(failures))
    sys.exit(1)
print("PASS: Open3D reads every output with the counts and bounds of report.json")
