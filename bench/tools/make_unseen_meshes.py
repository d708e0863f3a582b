#!/usr/bin/python3
"""Three objects for checking the scan and two-turn goals on shapes no setting
was chosen on (README 11.9 and 11.11), written as PLY meshes for
`craftscan-bench scan --object mesh:FILE`:

  bunny.ply  the Stanford Bunny, from the ten range scans in
             ../shared/data/clouds/bunny aligned by bun.conf (each line:
             file, translation t, quaternion q as i j k r; a point p of the
             scan goes to R(q̄) p + t, q̄ the conjugate), screened Poisson (Open3D,
             depth 9), cut back to within 1 mm of the scan points, largest
             component, decimated to 50 000 triangles; scaled to 70 mm along
             its length, +z up, centred on x = y = 0, lowest point at z = 0.
  torus.ply  a ring standing on its edge (radii 25 and 10 mm): symmetric
             about its own axis, so a second turn laid flat must be refused.
  statue.ply a figurine of primitives, 54 × 30 × 64 mm: a plinth (44 × 30
             × 8 mm), an ellipsoid body, a head with a conical nose, one arm
             held out with a hand; overlapping solids, the hidden parts of
             their surfaces never seen (stop 64).

  /usr/bin/python3 bench/tools/make_unseen_meshes.py [--data ../shared/data] [--out DIR]

Needs Debian's python3-open3d (scripts/setup installs it). The files are
derived from the Stanford data: keep them out of the repository.
"""
import argparse
import os
import sys

import numpy as np
import open3d as o3d


def bunny(data_dir):
    folder = os.path.join(data_dir, "clouds", "bunny")
    parts = []
    with open(os.path.join(folder, "bun.conf")) as conf:
        for line in conf:
            f = line.split()
            if len(f) < 9 or f[0] != "bmesh":
                continue
            t = np.array([float(v) for v in f[2:5]])
            qi, qj, qk, qr = (float(v) for v in f[5:9])
            rot = o3d.geometry.get_rotation_matrix_from_quaternion([qr, -qi, -qj, -qk])
            points = np.asarray(o3d.io.read_point_cloud(os.path.join(folder, f[1])).points)
            parts.append(points @ rot.T + t)
    if not parts:
        sys.exit(f"no 'bmesh' lines in {folder}/bun.conf")
    p = np.vstack(parts)
    p = p[:, [0, 2, 1]]
    p[:, 1] *= -1  # y up -> z up
    p = (p - p.min(0)) * 1000.0 * (70.0 / 175.0)  # metres -> mm, ~70 mm long
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(0.3)
    cloud, _ = cloud.remove_statistical_outlier(20, 2.0)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.5, max_nn=30))
    cloud.orient_normals_consistent_tangent_plane(20)
    pts, nrm = np.asarray(cloud.points), np.asarray(cloud.normals)
    if np.mean(np.sum((pts - pts.mean(0)) * nrm, 1)) < 0:
        cloud.normals = o3d.utility.Vector3dVector(-nrm)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=9)
    mesh = mesh.crop(cloud.get_axis_aligned_bounding_box())
    tree = o3d.geometry.KDTreeFlann(cloud)
    far = [tree.search_knn_vector_3d(v, 1)[2][0] > 1.0 for v in np.asarray(mesh.vertices)]
    mesh.remove_vertices_by_mask(far)
    labels, counts, _ = mesh.cluster_connected_triangles()
    mesh.remove_triangles_by_mask(np.asarray(labels) != int(np.argmax(np.asarray(counts))))
    mesh.remove_unreferenced_vertices()
    return mesh.simplify_quadric_decimation(50000)


def torus():
    mesh = o3d.geometry.TriangleMesh.create_torus(
        torus_radius=25, tube_radius=10, radial_resolution=120, tubular_resolution=60)
    v = np.asarray(mesh.vertices)[:, [0, 2, 1]]  # its axis along y: standing on its edge
    mesh.vertices = o3d.utility.Vector3dVector(v)
    return mesh


def statue():
    def placed(mesh, scale=(1, 1, 1), rotation=None, at=(0, 0, 0)):
        v = np.asarray(mesh.vertices) * np.array(scale)
        if rotation is not None:
            v = v @ rotation.T
        mesh.vertices = o3d.utility.Vector3dVector(v + np.array(at))
        return mesh

    def about_y(deg):
        return o3d.geometry.get_rotation_matrix_from_axis_angle([0, np.deg2rad(deg), 0])

    g = o3d.geometry.TriangleMesh
    parts = [
        placed(g.create_box(44, 30, 8), at=(-22, -15, 0)),  # plinth
        placed(g.create_sphere(1, resolution=60), scale=(13, 10, 22), at=(0, 0, 28)),  # body
        placed(g.create_sphere(8.5, resolution=50), at=(2, -1, 55)),  # head
        placed(g.create_cylinder(3.2, 28, resolution=40, split=8), rotation=about_y(-50),
               at=(16, 0, 34)),  # arm
        placed(g.create_sphere(4.5, resolution=30), at=(27, 0, 25)),  # hand
        placed(g.create_cone(2.5, 6, resolution=30), rotation=about_y(90), at=(9, -1, 55)),  # nose
    ]
    mesh = parts[0]
    for part in parts[1:]:
        mesh += part
    return mesh


def seat(mesh):
    v = np.asarray(mesh.vertices)
    v = v - [v[:, 0].mean(), v[:, 1].mean(), v[:, 2].min()]
    mesh.vertices = o3d.utility.Vector3dVector(v)
    return mesh


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=os.path.join(here, "..", "..", "..", "shared", "data"))
    parser.add_argument("--out", default=".")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    for name, mesh in (("bunny", bunny(args.data)), ("torus", torus()), ("statue", statue())):
        mesh = seat(mesh)
        path = os.path.join(args.out, name + ".ply")
        if not o3d.io.write_triangle_mesh(path, mesh, write_ascii=False,
                                          write_vertex_normals=False, write_vertex_colors=False):
            sys.exit(f"cannot write {path}")
        v = np.asarray(mesh.vertices)
        size = " × ".join(f"{e:.1f}" for e in v.max(0) - v.min(0))
        print(f"{path}: {len(mesh.triangles)} triangles, {size} mm")


if __name__ == "__main__":
    main()
