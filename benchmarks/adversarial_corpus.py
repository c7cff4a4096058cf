"""Adversarial input corpus: every mesh-reading CLI subcommand on broken, hostile and odd files.

Generates a folder of adversarial files (truncated, garbage, huge declared counts, NaN/inf and
1e300 coordinates, out-of-range / negative / float indices, empty, non-manifold, disconnected,
degenerate, duplicate faces, binary junk, wrong encodings, directories instead of files, ...) and
adversarial side files (labels, maps, seeds, ``.vts``, constraints) and command-line arguments;
runs ``shape-toolkit`` on each with a timeout and classifies every run:

- ``rejected``: exit code 2, exactly one line on stderr (a warning line counts too), no traceback,
  nothing on stdout (a clean refusal);
- ``success``: exit code 0, valid JSON on stdout without NaN / Infinity and without ``null`` where a
  number is expected (every key but the optional ones of :data:`NULLABLE`), at most one stderr line;
- ``failure``: anything else (traceback, internal error exit 1, other exit code, hang, bad JSON, a
  null metric, a second warning line, a multi-line rejection).

Issue 27 widened it: coordinates at 1e200 / 1e250 / 1e300 (alone and mixed with normal ones; session 40 added 1e100,
1e-100 and 1e-30),
degenerate meshes (zero area, identical or repeated vertices, 1e-300 scale) evaluated with maps and
labels of their own size, tiny and odd meshes (one triangle, two, a polygon fan, a non-manifold fan,
a tetrahedron) as either side of ``transfer-labels``, constraints given to segmenters that take none,
HTML (``<script>``) and LaTeX (``$\frac{a}{b}$``, ``\begin{x}``) and control characters in file
names, plugin names, presets and parameters, ``--param`` tables; and the commands ``geodesics``,
``describe``, ``constraints``, ``track`` and ``view --png``.

Writes ``benchmarks/results/adversarial.md`` (corpus size, counts, every failure).

    python benchmarks/adversarial_corpus.py [--out DIR] [--jobs 2] [--timeout 180] [--commands info,clean]

``tests/test_adversarial.py`` runs a fast subset in-process through ``shape_toolkit.cli.main``.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "adversarial.md"

#: strings that end up in outputs (shape names, labels, plugin names): HTML, LaTeX, control characters
NASTY_STRINGS = ("<script>alert(1)</script>", "$\\frac{a}{b}$", "\\begin{x}", "$\\frac{a$", "a\nb", "tab\there")
#: the same as file names ('/' cannot be in one)
NASTY_NAMES = ("<script>alert(1)<script>", "$\\frac{a}{b}$", "\\begin{x}", "$\\frac{a$", "new\nline")

#: JSON keys whose value may be null in a success (optional outputs, inputs not given); a null under
#: any other key is a metric or count that could not be computed: a failure
NULLABLE = frozenset({
    "ply", "output", "png", "gif", "ply_dir", "eigenvector", "dask", "seeds", "truth",  # outputs/inputs not asked for
    "n_constraints",  # segment without --constraints
    "proxy",  # match: None when the shapes were matched at full resolution (no proxy, issue 29)
    "ambiguity",  # match: None for a pipeline without candidates to compare (only best-of, auto, has them)
    "rival",  # match's ambiguity: None when no candidate lies RIVAL_DISTANCE or more from the kept map
    "settled",  # match: None when best-of ran every frame (its first maps disagreed) or the pipeline has no best-of
    "seeds_torn",  # match: None without --seeds, or for a target cloud with no surface to measure the seeds on
    "preset", "K", "times", "max_keypoints",  # parameters whose default is None, echoed as given
    "n_embedding", "output_dim",  # csc's parameters whose default is None
    "reason",  # a segmentation's constraint report: None when every constraint is kept
    "bic_curve_", "bic_monotone_",  # eigvec-gmm's BIC scan: None when k is given (no scan)
})

# -- corpus
_PLY_HEAD = "ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"


def _good_mesh():
    from shape_toolkit.data.generate import icosphere

    return icosphere(2)  # 162 vertices, 320 faces: fast for every command


def _off(v, f) -> str:
    head = f"OFF\n{len(v)} {len(f)} 0\n"
    return head + "".join(" ".join(map(repr, map(float, r))) + "\n" for r in v) + "".join(
        "3 " + " ".join(str(int(i)) for i in r) + "\n" for r in f
    )


def _ply_binary(v, f, *, nf=None, count=None, count_type="uchar", index_type="int", index_dtype="<i4",
                count_dtype="u1") -> bytes:
    """A binary PLY of vertices ``v`` and faces ``f``; ``nf`` a face count to declare instead of ``len(f)``,
    ``count`` a list length to write before every face instead of its own."""
    head = _PLY_HEAD.format(fmt="binary_little_endian", nv=len(v))
    head += f"element face {len(f) if nf is None else nf}\n"
    head += f"property list {count_type} {index_type} vertex_indices\nend_header\n"
    body = np.asarray(v, dtype="<f4").tobytes()
    for r in f:
        n = len(r) if count is None else count
        body += np.array([n], dtype=count_dtype).tobytes() + np.asarray(r, dtype=index_dtype).tobytes()
    return head.encode() + body


def mesh_corpus(folder: Path) -> dict[str, Path]:
    """Write the adversarial mesh / point-cloud files; returns {case name: path}."""
    from shape_toolkit.io.mesh import save_shape

    folder.mkdir(parents=True, exist_ok=True)
    s = _good_mesh()
    v, f = s.vertices, s.faces
    tri_v = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    files: dict[str, bytes | str | None] = {}
    good_off = _off(v, f)
    # -- controls (must succeed)
    files["good.off"] = good_off
    # -- emptiness, truncation, garbage
    files.update({f"empty.{ext}": "" for ext in ("off", "ply", "stl", "pcd")})
    files["whitespace.obj"] = "\n\n   \n"
    files["only_header.off"] = "OFF\n"
    files["truncated_half.off"] = good_off[: len(good_off) // 2]
    files["truncated_counts.off"] = "OFF\n10 2 0\n0 0 0\n1 0 0\n"
    files["garbage_text.off"] = "OFF\n3 1 0\nhello world !\n1 0 0\n0 1 0\n3 0 1 2\n"
    files["random_bytes.off"] = np.random.default_rng(0).bytes(4096)
    files["random_bytes.ply"] = b"ply\n" + np.random.default_rng(1).bytes(4096)
    files["random_bytes.stl"] = np.random.default_rng(2).bytes(84 + 50 * 3 + 7)
    files["random_bytes.pcd"] = np.random.default_rng(3).bytes(2048)
    files["random_bytes.obj"] = np.random.default_rng(4).bytes(2048)
    files["random_bytes.xyz"] = np.random.default_rng(5).bytes(2048)
    files["nul_bytes.off"] = b"\x00" * 1000
    files["utf16.off"] = good_off.encode("utf-16")
    files["latin1_comment.off"] = ("# caf\xe9 mesh\n" + good_off).encode("latin-1")
    files["bom_utf8.obj"] = "\ufeffv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".encode()
    files["wrong_magic.off"] = "COFFX\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    files["ply_as_off.off"] = _ply_binary(tri_v, [[0, 1, 2]])
    files["off_as_ply.ply"] = good_off
    # -- huge declared counts
    files["huge_count.off"] = "OFF\n999999999999999999999 1 0\n0 0 0\n"
    files["big_count.off"] = "OFF\n40000000 40000000 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    files["negative_count.off"] = "OFF\n-3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    files["huge_count_ascii.ply"] = (_PLY_HEAD.format(fmt="ascii", nv=30000000) + "end_header\n0 0 0\n")
    files["huge_count_binary.ply"] = _ply_binary(tri_v, [[0, 1, 2]], nf=40000000)
    files["empty_faces_binary.ply"] = _ply_binary(tri_v, [[]] * 200000)
    files["huge_count.pcd"] = (b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\n"
                               b"HEIGHT 1\nPOINTS 900000000\nDATA binary\n") + b"\x00" * 12
    files["huge_count.stl"] = b"\x00" * 80 + struct.pack("<I", 4000000000) + b"\x00" * 50
    # -- numbers
    files["nan.off"] = "OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n"
    files["inf.obj"] = "v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n"
    files["overflow_float.xyz"] = "0 0 0\n1e999 0 0\n0 1 0\n"
    files["coords_1e300.off"] = _off(v * 1e300, f)
    files["coords_1e-300.off"] = _off(v * 1e-300, f)
    files["coords_1e-320_subnormal.off"] = _off(v * 1e-320, f)
    # inside the range a shape is built in, outside the computations' (products of two areas; session 40); and 1e-30,
    # inside both (libigl's exact geodesics had looped forever there: tests/test_extreme_scales_s40.py)
    files["coords_1e100.off"] = _off(v * 1e100, f)
    files["coords_1e-100.off"] = _off(v * 1e-100, f)
    files["coords_1e-30.off"] = _off(v * 1e-30, f)
    files["coords_offset_1e15.off"] = _off(v + 1e15, f)
    files["index_out_of_range.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"
    files["index_negative.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"
    files["index_huge.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 99999999999999999999999999\n"
    files["index_float.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n"
    files["index_zero.obj"] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"
    files["index_negative_rel.obj"] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -9\n"
    files["index_float_ascii.ply"] = (_PLY_HEAD.format(fmt="ascii", nv=3) + "element face 1\n"
                                      "property list uchar float vertex_indices\nend_header\n"
                                      "0 0 0\n1 0 0\n0 1 0\n3 0.5 1 2\n")
    files["index_float_binary.ply"] = _ply_binary(tri_v, [[0.5, 1, 2]], index_type="float", index_dtype="<f4")
    files["index_nan_binary.ply"] = _ply_binary(tri_v, [[np.nan, 1, 2]], index_type="float", index_dtype="<f4")
    files["list_count_negative.ply"] = _ply_binary(tri_v, [[0, 1, 2]], count=-1, count_type="char", count_dtype="i1")
    files["list_count_negative_ascii.ply"] = (_PLY_HEAD.format(fmt="ascii", nv=3) + "element face 1\n"
                                              "property list char int vertex_indices\nend_header\n"
                                              "0 0 0\n1 0 0\n0 1 0\n-1 0 1 2\n")
    files["list_count_float.ply"] = _ply_binary(tri_v, [[0, 1, 2]], count_type="float", count_dtype="<f4")
    files["pcd_count0.pcd"] = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 0 1\nWIDTH 2\n"
                               "HEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3\n4 5 6\n")
    files["pcd_size3.pcd"] = (b"VERSION 0.7\nFIELDS x y z\nSIZE 3 3 3\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\n"
                              b"HEIGHT 1\nPOINTS 1\nDATA binary\n") + b"\x00" * 9
    files["pcd_nodata.pcd"] = "VERSION 0.7\nFIELDS x y z\nPOINTS 1\n"
    files["pcd_compressed_junk.pcd"] = (b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                                        b"WIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA binary_compressed\n") + b"\x01" * 20
    files["stl_ascii_truncated.stl"] = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
    files["stl_ascii_text.stl"] = "solid x\nfacet normal 0 0 1\nouter loop\nvertex a b c\nvertex 1 0 0\n" \
                                  "vertex 0 1 0\nendloop\nendfacet\nendsolid\n"
    files["ply_unknown_format.ply"] = _PLY_HEAD.format(fmt="binary_middle_endian", nv=1) + "end_header\n"
    files["ply_no_vertex.ply"] = "ply\nformat ascii 1.0\nelement face 0\nend_header\n"
    files["ply_bad_property.ply"] = "ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n0\n"
    files["ply_dup_property.ply"] = (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
                                     b"property float x\nproperty float z\nend_header\n") + b"\x00" * 12
    # -- topology and geometry defects
    files["duplicate_faces.off"] = _off(v, np.concatenate([f, f[:40]]))
    files["flipped_duplicate_faces.off"] = _off(v, np.concatenate([f, f[:40, ::-1]]))
    files["degenerate_faces.off"] = _off(np.r_[v, [[0.5, 0.5, 0.5]]], np.r_[f, [[0, 0, 1], [2, 2, 2]]])
    files["zero_area.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n"
    files["all_same_point.xyz"] = "1 1 1\n" * 50
    files["single_point.xyz"] = "1 2 3\n"
    files["two_points.pcd"] = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\n"
                               "HEIGHT 1\nPOINTS 2\nDATA ascii\n0 0 0\n1 0 0\n")
    files["single_triangle.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    files["non_manifold_edge.off"] = _off(np.r_[v, [[3.0, 3.0, 3.0]]], np.r_[f, [[f[0, 0], f[0, 1], len(v)]]])
    files["bowtie.off"] = _off([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0]], [[0, 1, 2], [0, 3, 4]])
    files["disconnected.off"] = _off(np.r_[v, v + 5.0], np.r_[f, f + len(v)])
    files["unreferenced_vertices.off"] = _off(np.r_[v, [[9.0, 9.0, 9.0]] * 5], f)
    files["unreferenced_vertices_first.off"] = _off(np.r_[[[9.0, 9.0, 9.0]] * 5, v], f + 5)
    # session 34: a triangle soup (every face its own corners), a sphere cut along unwelded vertices, half the faces
    # flipped
    files["triangle_soup.off"] = _off(np.asarray(v)[np.asarray(f)].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3))
    upper = np.asarray(v)[np.asarray(f)].mean(axis=1)[:, 2] > 0
    twin = np.full(len(v), -1)
    twin[np.unique(np.asarray(f)[upper])] = len(v) + np.arange(len(np.unique(np.asarray(f)[upper])))
    cut_f = np.array(f)
    cut_f[upper] = twin[np.asarray(f)[upper]]
    files["unwelded_seam.off"] = _off(np.r_[v, np.asarray(v)[np.unique(np.asarray(f)[upper])]], cut_f)
    mixed_f = np.array(f)
    mixed_f[upper] = mixed_f[upper][:, ::-1]
    files["mixed_orientation.off"] = _off(v, mixed_f)
    files["polygons.obj"] = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf 1 2 5\n"
    files["face_two_vertices.obj"] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n"
    files["point_cloud.xyz"] = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in v.tolist())
    # clouds whose points' neighbourhoods are collinear: one line, two parallel lines (a curve, not a surface)
    line = np.column_stack([np.linspace(0, 1, 200), np.zeros(200), np.zeros(200)])
    files["collinear.xyz"] = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in line.tolist())
    files["two_lines.xyz"] = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in np.r_[line, line + [0, 1, 0]].tolist())
    # -- issue 27: extreme coordinates, alone and mixed with normal ones
    for e in (200, 250):
        files[f"coords_1e{e}.off"] = _off(v * 10.0**e, f)
    one_far = v.copy()
    one_far[0] = [1e300, 0.0, 0.0]
    files["coords_mixed_1e300.off"] = _off(one_far, f)
    few_far = v.copy()
    few_far[:5] *= 1e200
    files["coords_mixed_1e200.off"] = _off(few_far, f)
    files["coords_mixed_1e250.xyz"] = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in np.r_[v, [[1e250, 0, 0]]].tolist())
    half_tiny = v.copy()
    half_tiny[: len(v) // 2] *= 1e-300
    files["coords_mixed_1e-300.off"] = _off(half_tiny, f)
    # -- degenerate meshes (zero area; identical, repeated or 1e-300 vertices)
    files["all_identical.off"] = "OFF\n4 2 0\n" + "1 1 1\n" * 4 + "3 0 1 2\n3 0 2 3\n"
    files["repeated_vertices.off"] = _off([[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3], [1, 2, 3]])
    files["collinear_fan.off"] = _off([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [[0, 1, 2], [0, 2, 3]])
    files["zero_area_1e-300.off"] = "OFF\n3 1 0\n0 0 0\n1e-300 0 0\n2e-300 0 0\n3 0 1 2\n"
    files["triangle_1e-300.off"] = "OFF\n3 1 0\n0 0 0\n1e-300 0 0\n0 1e-300 0\n3 0 1 2\n"
    files["repeated_index_faces.off"] = _off([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 2]])
    # -- tiny and odd meshes
    files["two_triangles.off"] = _off([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    ang = 2 * np.pi * np.arange(6) / 6
    fan_v = np.r_[[[0.0, 0.0, 0.0]], np.c_[np.cos(ang), np.sin(ang), np.zeros(6)]]
    files["polygon_fan.off"] = _off(fan_v, [[0, 1 + i, 1 + (i + 1) % 6] for i in range(6)])
    files["polygon_hexagon.obj"] = "".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in fan_v[1:].tolist()) \
        + "f 1 2 3 4 5 6\n"
    files["non_manifold_fan.off"] = _off([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]],
                                         [[0, 1, 2], [0, 1, 3], [0, 1, 4]])
    files["tetrahedron.off"] = _off([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                                    [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    # -- point clouds with their own normals (session 42): bad values are dropped or refused, bad signs mended
    sphere_n = v / np.linalg.norm(v, axis=1, keepdims=True)

    def cloud_ply(normals) -> str:
        head = (f"ply\nformat ascii 1.0\nelement vertex {len(v)}\n" + "".join(
            f"property double {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz")) + "end_header\n")
        return head + "".join(" ".join(repr(float(x)) for x in (*p, *n)) + "\n" for p, n in zip(v, normals))

    files["normals_good.ply"] = cloud_ply(sphere_n)
    files["normals_nan.ply"] = cloud_ply(np.where(np.arange(len(v))[:, None] == 3, np.nan, sphere_n))
    files["normals_zero.ply"] = cloud_ply(np.where(np.arange(len(v))[:, None] == 3, 0.0, sphere_n))
    files["normals_1e308.ply"] = cloud_ply(sphere_n * 1e308)
    files["normals_inward.ply"] = cloud_ply(-sphere_n)
    files["normals_random_signs.ply"] = cloud_ply(sphere_n * np.random.default_rng(2).choice([-1.0, 1.0], (len(v), 1)))
    files["noff_cloud_without_normals.off"] = f"NOFF\n{len(v)} 0 0\n" + "".join(
        " ".join(repr(float(x)) for x in p) + "\n" for p in v)
    # -- clouds whose kNN graphs fall apart (session 43): one surface sampled in rings (joined by its own local
    # triangulations: every command works), two spheres far apart (kept apart: refused or segmented piece by piece)
    rings = []
    for z in np.arange(-9.25, 10.0, 1.5):  # an ellipsoid (1, 1, 10), rings of 20 points 1.5 apart along its axis
        r, t = np.sqrt(max(1.0 - (z / 10.0) ** 2, 0.0)), np.arange(20) * np.pi / 10 + 0.1 * z
        rings.append(np.c_[r * np.cos(t), r * np.sin(t), np.full(20, z)])
    files["rings_cloud.xyz"] = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in np.vstack(rings).tolist())
    ball = sphere_n[np.unique(np.round(sphere_n, 12), axis=0, return_index=True)[1]]
    two = np.r_[ball, ball + [20, 0, 0]]
    files["two_spheres_cloud.xyz"] = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in two.tolist())
    # OBJ clouds with normals: one vn per v (read), one vn short (not paired: estimated), a NaN normal (estimated)
    obj_v = "".join("v " + " ".join(repr(float(x)) for x in p) + "\n" for p in v)
    obj_vn = ["vn " + " ".join(repr(float(x)) for x in n) + "\n" for n in sphere_n]
    files["obj_cloud_normals.obj"] = obj_v + "".join(obj_vn)
    files["obj_cloud_vn_short.obj"] = obj_v + "".join(obj_vn[1:])
    files["obj_cloud_vn_nan.obj"] = obj_v + "".join(obj_vn[:3]) + "vn nan nan nan\n" + "".join(obj_vn[4:])
    # -- names that end up in outputs: HTML, LaTeX, control characters
    for name in NASTY_NAMES:
        files[f"{name}.off"] = good_off
    for name, content in files.items():
        (folder / name).write_bytes(content.encode() if isinstance(content, str) else content)
    for name in ("good_binary.ply", "good_binary.stl", "good.obj", "good.pcd"):
        save_shape(s, folder / name, binary="binary" in name)
    (folder / "directory.off").mkdir(exist_ok=True)
    out = {p.name: p for p in sorted(folder.iterdir())}
    out["missing.off"] = folder / "missing.off"
    out["unknown_ext.abc"] = folder / "unknown_ext.abc"
    (folder / "unknown_ext.abc").write_text("1 2 3\n")
    return out


def side_corpus(folder: Path, n_vertices: int, n_faces: int) -> dict[str, dict[str, Path]]:
    """Adversarial labels / map / seeds / vts / constraints files and the good ones."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    n = n_vertices
    out: dict[str, dict[str, Path]] = {"good": {}, "labels": {}, "map": {}, "vts": {}, "seeds": {}, "constraints": {}}

    def ints(a) -> str:
        return "".join(f"{int(x)}\n" for x in a)

    def put(kind: str, case: str, name: str, content: bytes | str) -> None:
        out[kind][case] = folder / name
        out[kind][case].write_bytes(content if isinstance(content, bytes) else content.encode())

    bad_int_files: dict[str, bytes | str] = {
        "empty": "",
        "words": "1\n2\nthree\n",
        "float": "1.5\n" * 3,
        "double_minus": "1\n--5\n",
        "underscore": "1_0\n2\n",
        "unicode_digits": "\u0663\n\u0664\n",
        "huge": "1\n99999999999999999999999\n",
        "binary": rng.bytes(500),
        "utf16": "1\n2\n".encode("utf-16"),
        "latin1": "1\n\xe9\n".encode("latin-1"),
        "nan": "nan\n1\n",
    }
    good = {
        "labels": ints(rng.integers(0, 4, n)),
        "seg": ints(rng.integers(0, 4, n_faces)),
        "map": ints(np.arange(n)),
        "vts": ints(np.arange(1, n + 1, 5)),
        "seeds": "0 0\n5 5\n10 10\n",
        "constraints.json": json.dumps({"must_link": [[0, 1]], "cannot_link": [[0, 100]]}),
    }
    for kind, text in good.items():
        put("good", kind.split(".")[0], f"good.{kind}", text)
    #: (kind, case): (file name, content), the bad files of one kind only
    own_kind = {
        ("labels", "wrong_length"): ("short.labels", ints([0, 1, 2])),
        ("labels", "negative"): ("negative.labels", ints(-rng.integers(1, 5, n))),
        ("labels", "all_unique"): ("unique.labels", ints(np.arange(n) * 7919)),
        ("labels", "extreme"): ("extreme.labels", ints(rng.choice([-(2**62), 2**62, 0], n))),
        ("map", "out_of_range"): ("range.map", ints(np.full(n, n + 3))),
        ("map", "all_unmatched"): ("unmatched.map", ints(np.full(n, -1))),
        ("map", "below_minus_one"): ("minus.map", ints(np.full(n, -7))),
        ("vts", "zero_based"): ("zero.vts", ints(np.arange(0, n, 5))),
        ("vts", "out_of_range"): ("range.vts", ints([1, n + 10])),
    }
    seeds = {"three_columns": "0 1 2\n", "out_of_range": f"0 {n + 4}\n", "negative": "-1 3\n",
             "comma": "0,0\n1,1\n", "comment_only": "# nothing\n"}
    own_kind.update({("seeds", case): (f"{case}.seeds", text) for case, text in seeds.items()})
    cons = {
        "not_json": "{must_link: [[0, 1]]}",
        "list": "[[0, 1]]",
        "unknown_key": '{"must": [[0, 1]]}',
        "out_of_range": json.dumps({"must_link": [[0, n + 5]]}),
        "self_pair": '{"must_link": [[3, 3]]}',
        "contradiction": '{"must_link": [[0, 1], [1, 2]], "cannot_link": [[0, 2]]}',
        "float_ids": '{"must_link": [[0.5, 1]]}',
        "huge_ids": '{"must_link": [[0, 99999999999999999999999999]]}',
        "nan_ids": '{"must_link": [[NaN, 1]]}',
        "ragged": '{"must_link": [[0, 1], [2]]}',
        "strings": '{"must_link": [["a", "b"]]}',
        "bools": '{"must_link": [[true, false]]}',
        "deep": "[" * 100000 + "]" * 100000,
        "binary": rng.bytes(300),
        "utf16": '{"must_link": [[0, 1]]}'.encode("utf-16"),
        "empty": "",
    }
    for kind in ("labels", "map", "vts", "seeds"):
        for name, content in bad_int_files.items():
            if kind == "seeds" and name not in ("empty", "binary", "utf16", "latin1"):
                content = content if isinstance(content, bytes) else "".join(
                    f"{t} {t}\n" for t in content.split()) or content
            put(kind, name, f"{name}.{kind}", content)
        out[kind]["directory"] = folder / f"dir.{kind}"
        out[kind]["directory"].mkdir(exist_ok=True)
        out[kind]["missing"] = folder / f"missing.{kind}"
    for (kind, case), (name, content) in own_kind.items():
        put(kind, case, name, content)
    for case, content in cons.items():
        put("constraints", case, f"{case}.constraints.json", content)
    out["constraints"]["directory"] = folder / "dir.constraints"
    out["constraints"]["directory"].mkdir(exist_ok=True)
    return out


# -- runs
@dataclass
class Run:
    case: str
    argv: list[str]
    code: int | None = None
    stdout: str = ""
    stderr: str = ""
    verdict: str = ""
    why: str = ""


def own_side_files(mesh: Path, folder: Path) -> dict[str, Path] | None:
    """Side files sized to ``mesh`` (labels per vertex and per face, the identity map, ``.vts`` truth, a
    labels file of the vertex ids), so that its runs reach the computation instead of stopping at a
    length mismatch; None when the mesh does not load (its runs are refused on load anyway)."""
    from shape_toolkit.io.mesh import load_shape

    try:
        s = load_shape(mesh)
    except Exception:  # noqa: BLE001 - a refused file: the good side files serve
        return None
    n, m = s.n_vertices, s.n_faces
    stem = folder / f"{len(list(folder.iterdir())):04d}"
    out = {"labels": Path(f"{stem}.labels"), "seg": Path(f"{stem}.seg"), "map": Path(f"{stem}.map"),
           "vts": Path(f"{stem}.vts")}
    out["labels"].write_text("".join(f"{i % 3}\n" for i in range(n)))
    out["seg"].write_text("".join(f"{i % 2}\n" for i in range(max(m, 1))) if m else "0\n")
    out["map"].write_text("".join(f"{i}\n" for i in range(n)))
    out["vts"].write_text("".join(f"{i}\n" for i in range(1, n + 1, max(1, n // 30))))
    return out


def mesh_runs(mesh: Path, name: str, side: dict, out: Path, *, commands: tuple[str, ...] | None = None,
              own: dict[str, Path] | None = None) -> list[Run]:
    """Every mesh-reading subcommand with ``mesh`` in the position of the shape under test; ``own``: side
    files sized to the mesh (:func:`own_side_files`), else the good mesh's."""
    g, good = side["good"], str(side["good_mesh"])
    o = out / f"{abs(hash(name)) % 10**8:08d}"  # output names free of the mesh's odd characters
    m = str(mesh)
    mine = {kind: str(path) for kind, path in (own or g).items()}
    runs = {
        "info": ["info", m, "--json"],
        "clean": ["clean", m, "-o", f"{o}.clean.off", "--json"],
        "spectrum": ["spectrum", m, "-k", "6", "--json"],
        "keypoints": ["keypoints", m, "--json"],
        "segment": ["segment", m, "--method", "eigvec-gmm", "-k", "3", "-o", f"{o}.seg.txt", "--json"],
        "match": ["match", m, good, "--pipeline", "seed-growing", "-o", f"{o}.map", "--json", "--quiet"],
        "evaluate-map": ["evaluate-map", m, m, mine["map"], "--truth-src", mine["vts"], "--truth-dst", mine["vts"],
                         "--geodesics", "dijkstra", "--json"],
        "evaluate-segmentation": ["evaluate-segmentation", m, mine["labels"], "--truth", mine["seg"], "--json"],
        "transfer-labels": ["transfer-labels", good, str(g["labels"]), m, "-o", f"{o}.transfer.txt", "--json"],
        "transfer-labels from": ["transfer-labels", m, mine["labels"], good, "-o", f"{o}.from.txt", "--json"],
        "geodesics": ["geodesics", m, "--sources", "0", "--method", "dijkstra", "-o", f"{o}.geo.npz", "--json"],
        "describe": ["describe", m, "-o", f"{o}.hks.npz", "--json"],
        "constraints": ["constraints", m, mine["labels"], "-o", f"{o}.constraints.json", "--json"],
        "track": ["track", m, good, "--pipeline", "seed-growing", "-o", f"{o}.traj.npz", "--json", "--quiet"],
        "view": ["view", m, "--png", f"{o}.view.png", "--json"],
    }
    return [Run(f"{name} | {cmd}", argv) for cmd, argv in runs.items()
            if commands is None or cmd.split()[0] in commands]


def side_runs(side: dict, out: Path) -> list[Run]:
    """The side files (labels, maps, seeds, vts, constraints) and odd arguments on a good mesh."""
    g, good = side["good"], str(side["good_mesh"])
    labels, seg, vts, cons = str(g["labels"]), str(g["seg"]), str(g["vts"]), str(g["constraints"])
    gmm, kp = ["segment", good, "--method", "eigvec-gmm"], ["keypoints", good]
    s_out, dijkstra = ["-o", str(out / "s.txt"), "--json"], ["--geodesics", "dijkstra", "--json"]
    #: side-file kind -> [(what the case runs, its arguments with None where the side file goes)]
    uses = {
        "labels": [("evaluate-segmentation pred", ["evaluate-segmentation", good, None, "--truth", seg, "--json"]),
                   ("evaluate-segmentation truth", ["evaluate-segmentation", good, labels, "--truth", None, "--json"]),
                   ("transfer-labels", ["transfer-labels", good, None, good, "-o", str(out / "t.txt"), "--json"])],
        "map": [("evaluate-map", ["evaluate-map", good, good, None, "--truth-src", vts, "--truth-dst", vts,
                                  *dijkstra])],
        "vts": [("evaluate-map", ["evaluate-map", good, good, str(g["map"]), "--truth-src", None, "--truth-dst", vts,
                                  *dijkstra])],
        "seeds": [("match", ["match", good, good, "--pipeline", "seed-growing", "--seeds", None,
                             "-o", str(out / "m.map"), "--json", "--quiet"])],
        "constraints": [("segment", ["segment", good, "--method", "csc", "-k", "3", "--constraints", None,
                                     "-o", str(out / "c.txt"), "--json"])],
    }
    runs = [Run(f"{kind}:{name} | {what}", [str(p) if a is None else a for a in argv])
            for kind, cases in uses.items() for name, p in side[kind].items() for what, argv in cases]
    args = {
        "output missing folder": ["spectrum", good, "-k", "4", "-o", str(out / "no" / "such" / "x.npz"), "--json"],
        "output onto folder": ["clean", good, "-o", str(out), "--json"],
        "output onto folder (segment)": [*gmm, "-o", str(out), "--json"],
        "output onto folder (match)": ["match", good, good, "--pipeline", "seed-growing", "-o", str(out), "--quiet"],
        "output onto folder (keypoints)": [*kp, "-o", str(out), "--json"],
        "output onto folder (transfer)": ["transfer-labels", good, labels, good, "-o", str(out)],
        "output is the input": ["clean", good, "-o", good, "--json"],
        "param not a number": ["spectrum", good, "--weighting", "gaussian", "--param", "bandwidth=abc", "--json"],
        "param not a number (keypoints)": [*kp, "--param", "t=abc", "--json"],
        "param not a number (segment)": [*gmm, "--param", "n_init=many", *s_out],
        "param NaN": [*kp, "--param", "t=NaN", "--json"],
        "param without =": [*kp, "--param", "t", "--json"],
        "param unknown": [*kp, "--param", "nope=1", "--json"],
        "random state negative": [*gmm, "--random-state", "-1", *s_out],
        "random state huge": [*gmm, "--random-state", "99999999999", *s_out],
        "k zero": ["spectrum", good, "-k", "0", "--json"],
        "k huge": ["spectrum", good, "-k", "100000", "--json"],
        "n segments zero": [*gmm, "-k", "0", "-o", str(out / "s.txt")],
        "remesh tiny edge": ["clean", good, "-o", str(out / "r.off"), "--remesh", "1e-9", "--json"],
        "remesh negative edge": ["clean", good, "-o", str(out / "r.off"), "--remesh", "-1", "--json"],
        "remesh nan edge": ["clean", good, "-o", str(out / "r.off"), "--remesh", "nan", "--json"],
        "unknown plugin": [*kp, "--detector", "nope", "--json"],
        "unknown preset": [*kp, "--preset", "nope", "--json"],
        "unknown pipeline": ["match", good, good, "--pipeline", "nope", "-o", str(out / "m.map")],
        "pipeline is a folder": ["match", good, good, "--pipeline", str(out), "-o", str(out / "m.map")],
        "truth folder empty": ["evaluate-segmentation", good, labels, "--truth", str(side["empty_dir"])],
        "map for the wrong shape": ["evaluate-map", good, str(side["other_mesh"]), str(g["map"]), "--truth-src", vts,
                                    "--truth-dst", vts, "--json"],
    }
    # --proxy (round 19's audit): bad sizes refused by the parser; the good mesh (162 vertices) through a proxy of 100
    m_out = ["-o", str(out / "m.map"), "--json", "--quiet"]
    for value in ("50", "-1", "1.5", "abc", "1e3"):
        args[f"proxy {value} (match)"] = ["match", good, good, "--pipeline", "zoomout", "--proxy", value, *m_out]
        args[f"proxy {value} (segment)"] = [*gmm, "-k", "3", "--proxy", value, *s_out]
    for value in ("50", "-1", "abc"):  # session 34: transfer-labels and track take --proxy too
        args[f"proxy {value} (transfer-labels)"] = ["transfer-labels", good, labels, good, "--proxy", value,
                                                    "-o", str(out / "t.txt"), "--json"]
        args[f"proxy {value} (track)"] = ["track", good, good, "--proxy", value, "-o", str(out / "t.npz"), "--json"]
    args["proxy 100 (transfer-labels)"] = ["transfer-labels", good, labels, good, "--proxy", "100",
                                           "-o", str(out / "t.txt"), "--json"]
    args["proxy 100 (track)"] = ["track", good, good, "--proxy", "100", "-o", str(out / "t.npz"), "--json", "--quiet"]
    many = out / "many_sources.txt"
    many.write_text("0\n" * 1_000_000)  # a million sources of a small mesh: refused before the mesh is read
    args["geodesics 1M sources"] = ["geodesics", good, "--sources", str(many), "--method", "dijkstra",
                                    "--memory-limit", "1", "-o", str(out / "g.npz"), "--json"]
    args["proxy 100 (match)"] = ["match", good, good, "--pipeline", "zoomout", "--proxy", "100", *m_out]
    args["proxy 100 (match, partial)"] = ["match", good, good, "--pipeline", "partial", "--proxy", "100", *m_out]
    args["proxy 100 (segment --faces)"] = ["segment", good, "-k", "3", "--proxy", "100", "--faces", *s_out]
    args["proxy 100 (segment, constraints)"] = ["segment", good, "--method", "csc", "-k", "3", "--proxy", "100",
                                                "--constraints", cons, *s_out]
    # issue 27: constraints given to segmenters that take none
    for method in ("eigvec-gmm", "spectral-clustering", "ncut", "sdf", "smoothed"):
        args[f"constraints to {method}"] = ["segment", good, "--method", method, "-k", "3", "--constraints", cons,
                                            "-o", str(out / "u.txt"), "--json"]
    args["constraints to smoothed csc"] = ["segment", good, "--method", "smoothed", "--param", "base=csc", "-k", "3",
                                           "--constraints", cons, "-o", str(out / "u.txt"), "--json"]
    # --param tables and lists where a name or number is expected
    for value in ('{"a":1}', "[1,2]"):
        args[f"param weighting={value} (spectrum)"] = ["spectrum", good, "--param", f"weighting={value}", "--json"]
        args[f"param weighting={value} (keypoints)"] = [*kp, "--param", f"weighting={value}", "--json"]
        args[f"param weighting={value} (segment)"] = [*gmm, "--param", f"weighting={value}", *s_out]
        args[f"param variant={value} (segment)"] = ["segment", good, "--method", "spectral-clustering", "-k", "3",
                                                    "--param", f"variant={value}", *s_out]
        args[f"param times={value} (describe)"] = ["describe", good, "--param", f"times={value}",
                                                   "-o", str(out / "d.npz"), "--json"]
        args[f"param t={value} (keypoints)"] = [*kp, "--param", f"t={value}", "--json"]
        args[f"param descriptor_params={value} (transfer-labels)"] = [
            "transfer-labels", good, labels, good, "--matcher", "fmap-zoomout", "--param",
            f"descriptor_params={value}", "-o", str(out / "t.txt"), "--json"]
    # HTML, LaTeX and control characters in every string argument that ends up in an output
    for i, text in enumerate(NASTY_STRINGS):
        args[f"nasty {i} segment --method"] = ["segment", good, "--method", text, *s_out]
        args[f"nasty {i} keypoints --detector"] = [*kp, "--detector", text, "--json"]
        args[f"nasty {i} keypoints --preset"] = [*kp, "--preset", text, "--json"]
        args[f"nasty {i} spectrum --weighting"] = ["spectrum", good, "--weighting", text, "-k", "4", "--json"]
        args[f"nasty {i} describe --descriptor"] = ["describe", good, "--descriptor", text, "-o", str(out / "d.npz")]
        args[f"nasty {i} match --pipeline"] = ["match", good, good, "--pipeline", text, "-o", str(out / "m.map")]
        args[f"nasty {i} transfer-labels --matcher"] = ["transfer-labels", good, labels, good, "--matcher", text,
                                                        "-o", str(out / "t.txt")]
        args[f"nasty {i} --param key"] = [*kp, "--param", f"{text}=1", "--json"]
        args[f"nasty {i} --param value"] = [*kp, "--param", f"t={text}", "--json"]
        args[f"nasty {i} --param laplacian"] = [*kp, "--param", f"laplacian={text}", "--json"]
        args[f"nasty {i} missing file"] = ["info", str(out / f"{text}.off"), "--json"]
        args[f"nasty {i} output name"] = [*gmm, "-k", "3", "-o", str(out / f"{text}.txt"), "--json"]
        args[f"nasty {i} track frames --png"] = ["track", str(side["nasty_meshes"][i % len(side["nasty_meshes"])]),
                                                 good, "--pipeline", "seed-growing", "-o", str(out / "tr.npz"),
                                                 "--png", str(out / "tr.png"), "--json", "--quiet"]
    runs.extend(Run(f"args:{name}", argv) for name, argv in args.items())
    return runs


def null_metrics(obj: object, path: str = "") -> list[str]:
    """JSON paths of the nulls in ``obj`` outside the optional keys of :data:`NULLABLE` and those its
    object explains in an ``undefined`` mapping (``{"genus": "defined for a closed ... mesh only"}``)."""
    out: list[str] = []
    if isinstance(obj, dict):
        explained = obj.get("undefined") if isinstance(obj.get("undefined"), dict) else {}
        for k, v in obj.items():
            if v is None:
                if k not in NULLABLE and not explained.get(k):
                    out.append(f"{path}.{k}")
            else:
                out.extend(null_metrics(v, f"{path}.{k}"))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.extend([f"{path}[{i}]"] if v is None else null_metrics(v, f"{path}[{i}]"))
    return out


def classify(run: Run) -> Run:
    """Set ``run.verdict`` to rejected / success / failure (see the module doc)."""
    err_lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    if run.code is None:
        run.verdict, run.why = "failure", "timeout"
    elif "Traceback" in run.stderr or "Traceback" in run.stdout:
        run.verdict, run.why = "failure", "traceback"
    elif run.code == 2:
        if len(err_lines) != 1:
            run.verdict, run.why = "failure", f"exit 2 with {len(err_lines)} stderr lines"
        elif "internal error" in err_lines[0]:
            run.verdict, run.why = "failure", f"exit 2 with an internal error: {err_lines[0][:200]}"
        elif run.stdout.strip():
            run.verdict, run.why = "failure", "exit 2 with output on stdout"
        else:
            run.verdict = "rejected"
    elif run.code == 0:
        try:
            data = json.loads(run.stdout, parse_constant=_refuse_constant)
        except ValueError as exc:
            run.verdict, run.why = "failure", f"invalid JSON ({exc})"
            return run
        nulls = null_metrics(data)
        if nulls:
            run.verdict, run.why = "failure", f"null where a number is expected: {', '.join(nulls[:5])}"
        elif len(err_lines) > 1:
            run.verdict, run.why = "failure", f"success with {len(err_lines)} stderr lines: {err_lines[0][:150]}"
        else:
            run.verdict = "success"
    else:
        run.verdict, run.why = "failure", f"exit {run.code}: {(err_lines or [''])[-1][:200]}"
    return run


def _refuse_constant(name: str):
    raise ValueError(f"{name} in JSON")


def execute(run: Run, timeout: float, cwd: Path) -> Run:
    """Run ``python -m shape_toolkit ARGV`` in a subprocess and classify it."""
    env = dict(os.environ, PYTHONWARNINGS="ignore::DeprecationWarning", OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    try:
        r = subprocess.run([sys.executable, "-m", "shape_toolkit", *run.argv], capture_output=True, text=True,
                           timeout=timeout, cwd=cwd, env=env, errors="replace")
        run.code, run.stdout, run.stderr = r.returncode, r.stdout, r.stderr
    except subprocess.TimeoutExpired:
        run.code = None
    return classify(run)


def build(folder: Path, *, commands: tuple[str, ...] | None = None) -> list[Run]:
    """Generate the corpus in ``folder`` and list its runs."""
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.io.mesh import save_shape

    s = _good_mesh()
    meshes = mesh_corpus(folder / "meshes")
    side: dict = side_corpus(folder / "side", s.n_vertices, s.n_faces)
    side["good_mesh"] = meshes["good.off"]
    side["other_mesh"] = folder / "side" / "other.off"
    save_shape(icosphere(1), side["other_mesh"])
    side["empty_dir"], out, own_dir = folder / "side" / "empty_dir", folder / "out", folder / "own"
    for d in (side["empty_dir"], out, own_dir):
        d.mkdir(exist_ok=True)
    side["nasty_meshes"] = [meshes[f"{n}.off"] for n in NASTY_NAMES]
    runs: list[Run] = []
    for name, path in meshes.items():
        own = own_side_files(path, own_dir) if path.is_file() else None
        runs.extend(mesh_runs(path, name, side, out, commands=commands, own=own))
    runs.extend(side_runs(side, out))
    return runs


def is_transient(run: Run) -> bool:
    """A run the machine stopped, not the input: exit 3, the CLI's code for a process killed or out of
    memory (on a shared machine another process's memory use can push any run over)."""
    return run.verdict == "failure" and run.code == 3 and "out of memory" in run.stderr


def retry_transient(runs: list[Run], timeout: float, cwd: Path) -> list[tuple[str, str]]:
    """Run each transient failure (:func:`is_transient`) once more, alone; its second verdict stands.
    Returns ``[(case, first why)]`` for the report, which lists them."""
    retried = []
    for r in runs:
        if is_transient(r):
            first = r.why
            execute(r, timeout, cwd)
            print(f"retried {r.case}: {r.verdict} {r.why}", flush=True)
            retried.append((r.case, first))
    return retried


def _md(text: str) -> str:
    """``text`` on one markdown line: control characters and backticks escaped."""
    return text.encode("unicode_escape").decode("ascii").replace("`", "'")


def report(runs: list[Run], n_files: int, seconds: float, path: Path = RESULTS,
           retried: list[tuple[str, str]] = ()) -> str:
    """Write the markdown report of ``runs`` (counts per verdict and command, every failure) to ``path``."""
    from shape_toolkit.bench.report import markdown_table

    counts = Counter(r.verdict for r in runs)
    by_cmd = Counter((r.argv[0], r.verdict) for r in runs)
    lines = [
        "# Adversarial input corpus",
        "",
        "Generated and run by `python benchmarks/adversarial_corpus.py` (every mesh-reading subcommand on",
        "every adversarial file, plus adversarial labels / maps / seeds / `.vts` / constraints files and",
        "arguments on a good mesh; subprocess per run, with a timeout).",
        "",
        f"- corpus: {n_files} files and folders; {len(runs)} runs; wall time {seconds:.0f} s",
        f"- **rejected** cleanly (exit 2, exactly one stderr line, no traceback, nothing on stdout): "
        f"{counts['rejected']}",
        f"- **success** (exit 0, valid JSON without NaN/Infinity or a null metric, at most one stderr line): "
        f"{counts['success']}",
        f"- **failure** (traceback, internal error, other exit code, hang, invalid JSON, null metric, a second "
        f"stderr line): {counts['failure']}",
        f"- run a second time (each listed below with its first verdict; the second counts): {len(retried)}",
        "",
        *markdown_table(["command", "rejected", "success", "failure"],
                        [[c, *(by_cmd[c, k] for k in ("rejected", "success", "failure"))]
                         for c in sorted({r.argv[0] for r in runs})]),
    ]
    fails = [r for r in runs if r.verdict == "failure"]
    verdict = {r.case: r.verdict for r in runs}
    lines += ["", "## Failures", ""]
    lines += [f"- `{_md(r.case)}`: {_md(r.why)}" for r in fails] or ["none"]
    if retried:
        lines += ["", "## Run a second time", ""]
        lines += [f"- `{_md(case)}` (first pass: {_md(why)}): now {verdict[case]}" for case, why in retried]
    lines += ["", "## Successes (accepted inputs)", ""]
    lines += [f"- `{_md(r.case)}`" for r in runs if r.verdict == "success"]
    text = "\n".join(lines) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=None, help="corpus folder (default: a temporary one)")
    ap.add_argument("--jobs", type=int, default=2, help="parallel runs (default 2)")
    ap.add_argument("--timeout", type=float, default=180.0, help="seconds per run (default 180)")
    ap.add_argument("--commands", default=None, help="comma-separated subset of subcommands")
    ap.add_argument("--report", default=str(RESULTS), help="markdown report path")
    args = ap.parse_args(argv)
    folder = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="adversarial-"))
    commands = tuple(args.commands.split(",")) if args.commands else None
    runs = build(folder, commands=commands)
    n_files = 1 + sum(len(list((folder / d).iterdir())) for d in ("meshes", "side", "own"))
    print(f"{len(runs)} runs on a corpus of {n_files} files in {folder}", flush=True)
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for done, r in enumerate(pool.map(lambda r: execute(r, args.timeout, folder / "out"), runs), 1):
            if r.verdict == "failure":
                print(f"[{done}/{len(runs)}] FAILURE {r.case}: {r.why}", flush=True)
            elif done % 50 == 0:
                print(f"[{done}/{len(runs)}] ...", flush=True)
    retried = retry_transient(runs, args.timeout, folder / "out")
    text = report(runs, n_files, time.perf_counter() - t0, Path(args.report), retried=retried)
    print(text.split("## Failures")[0])
    return 1 if any(r.verdict == "failure" for r in runs) else 0


if __name__ == "__main__":
    sys.exit(main())
