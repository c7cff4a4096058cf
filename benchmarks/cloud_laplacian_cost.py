"""CPU seconds of the point-cloud Laplacian, both constructions, on one cloud (issue 29, clouds at scale).

A cloud of ``N`` points sampled uniform in area on a mesh (the ``point-cloud`` corruption, ``random_state``
0); in one process, after a warm-up on a small cloud (imports): ``intrinsic-delaunay``'s weights with
``cloud_neighbors = "all"`` (robust_laplacian's construction) and ``"sheet"`` (the default), then the sheet
construction's stages apart (outward normals, local Delaunay triangles, ``mesh_laplacian``) and the local
surface of fmap-zoomout's orientation term (``cloud_surface``, its normals shared with the weighting). Run it
with one BLAS thread::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 TOOLKIT_DATA=/work/shared/data \\
        python benchmarks/cloud_laplacian_cost.py --points 5000 125000 [--mesh tosca5k/dog0.off]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import robust_laplacian

from shape_toolkit.core import surface
from shape_toolkit.data.corruptions import point_cloud
from shape_toolkit.io.mesh import load_shape
from shape_toolkit.plugins.weightings.intrinsic_delaunay import IntrinsicDelaunayWeighting, centred


def timed(f: Callable[..., Any], *args: Any) -> tuple[Any, float, float]:
    """``f(*args)``, its CPU seconds (this process) and wall seconds."""
    c, w = time.process_time(), time.perf_counter()
    out = f(*args)
    return out, time.process_time() - c, time.perf_counter() - w


def main() -> None:
    """Print one table row per cloud size and stage: CPU and wall seconds."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, nargs="+", default=[5000, 125000])
    ap.add_argument("--mesh", default="tosca5k/dog0.off", help="under $TOOLKIT_DATA")
    a = ap.parse_args()
    mesh = load_shape(Path(os.environ.get("TOOLKIT_DATA", "/work/shared/data")) / a.mesh)
    IntrinsicDelaunayWeighting().weigh(point_cloud(mesh, points=500, random_state=0)[0], None)  # warm-up
    print(f"| points | stage | CPU s | wall s |  ({a.mesh}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')})")
    print("|---|---|---|---|")
    for n in a.points:
        cloud = point_cloud(mesh, points=n, random_state=0)[0]
        v = np.ascontiguousarray(cloud.vertices)
        surface._NORMALS.clear()
        rows = [("weights, all neighbours", IntrinsicDelaunayWeighting(cloud_neighbors="all").weigh, cloud, None),
                ("weights, own sheet", IntrinsicDelaunayWeighting().weigh, cloud, None),
                ("  local surface after them (normals shared)", surface.cloud_surface, cloud)]
        for label, f, *args in rows:
            _, c, w = timed(f, *args)
            print(f"| {n} | {label} | {c:.2f} | {w:.2f} |", flush=True)
        surface._NORMALS.clear()
        N, c, w = timed(surface.outward_normals, v)
        print(f"| {n} | sheet stage: outward normals | {c:.2f} | {w:.2f} |", flush=True)
        F, c, w = timed(surface.local_delaunay_triangles, v, N, 30)
        print(f"| {n} | sheet stage: local Delaunay triangles ({len(F)}) | {c:.2f} | {w:.2f} |", flush=True)
        _, c, w = timed(robust_laplacian.mesh_laplacian, centred(v), np.ascontiguousarray(F), 1e-5)
        print(f"| {n} | sheet stage: mesh_laplacian | {c:.2f} | {w:.2f} |", flush=True)


if __name__ == "__main__":
    main()
