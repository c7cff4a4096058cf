"""Constrained spectral clustering, CSC (thesis Algorithm 4, section 5.3).

1. L-embedding: commute-time embedding ``X = Lambda^-1/2 U^T`` (eq. 5.1) with the ``p`` first
   non-null eigenpairs of the unnormalized Laplacian ``L = D - W``;
2. constraint propagation: for each must-link (cannot-link) pair ``(i, j)``, the vertices whose
   embedding lies in the hypersphere centred at ``(x_i + x_j) / 2`` of diameter
   ``||x_i - x_j||`` (eq. 5.6) form a volume; every graph edge with both ends in a must-link volume
   gets weight 1, in a cannot-link volume weight ``epsilon`` (cannot-links are applied last). The
   graph topology is unchanged: ``W_hat`` has the sparsity pattern of ``W``;
3. the modified Laplacian ``L_hat = D_hat - W_hat`` (eq. 5.4) and its embedding
   ``X_hat = Lambda_hat^-1/2 U_hat^T`` (eq. 5.5);
4. k-means on the rows of ``X_hat``.

Two documented choices where the text leaves room:

- ``output_dim`` (default ``k - 1``): step 3 reads "the ``k`` first non-null eigenpairs"; we use
  ``k - 1`` non-null ones by default, i.e. von Luxburg's "first ``k`` eigenvectors" once the constant
  one (which does not move k-means) is dropped. On the synthetic articulated shapes the extra
  ``k``-th mode made k-means split the large body in two (recall 0.70 vs 0.82); ``output_dim=k`` is
  the literal reading.
- ``cannot_mode`` (default ``"bisector"``): inside a cannot-link volume only the edges crossing the
  hyperplane that bisects the constrained pair (one end closer to ``x_i``, the other to ``x_j``) get
  ``epsilon``. Setting *every* edge of the volume to ``epsilon`` (``"volume"``, the literal rule)
  nearly isolates the volume's interior vertices, and for small ``epsilon`` the first eigenvectors of
  ``L_hat`` localise on them (observed: recall 0.19 with ``epsilon=1e-3``); the bisector rule cuts
  the volume in two instead and is insensitive to ``epsilon``.

Three departures from the literal text, all about *how* the constraints act, not what they mean:

- monotone re-weighting: inside a cannot-link volume an edge gets ``min(w_ij, epsilon)``, inside a
  must-link volume ``max(w_ij, must_weight)``. The thesis sets them *to* ``epsilon`` / 1, which is the
  same on its Gaussian vertex graph (weights far above ``epsilon``), but on the dual graph a sharp
  concave crease weighs ``1e-3 < epsilon``: the literal rule made the crease between two cannot-linked
  parts ten times stronger, the opposite of the constraint.
- ``kmeans_init`` (default ``"constraints"``): step 4's k-means starts from the centres of the
  must-link groups (connected components of the must-link pairs) in ``X_hat``, and each group's nodes
  stay in its cluster at every step: constrained k-means (Basu, Banerjee & Mooney 2002; farthest-first
  when there are more groups than ``k``, k-means++ for the missing centres when fewer; but see
  ``k_mismatch``), so two clicks of one must-link never land in two segments. With random
  starts (``"k-means++"``, the previous behaviour) k-means preferred splitting a large elongated part
  in two over separating two small clicked parts (a lower objective: the unnormalized Laplacian's
  balance bias), e.g. the PSB mechanical part 328 at a Rand index error of 0.43 with the clicks of a
  human whose own error there is 0.003. The thesis leaves the start of k-means open.
- ``k_mismatch`` (default ``"ncut"``): when the user clicked a number ``g >= 2`` of parts (must-link
  groups) other than ``k``, step 4 uses normalized cuts of ``W_hat`` (Shi and Malik's recursive
  two-way cuts, the splitting rule of the ``ncut`` segmenter; no cut separates a must-link group).
  Fewer clicks (``g < k``): the ``g`` clicked segments come from constrained k-means with ``g`` centres in
  all the columns of ``X_hat`` (``output_dim``, ``k - 1`` by default; the first ``g - 1`` columns alone,
  the earlier rule, can hold only the modes of one large part: on a strip with two bumps behind concave
  creases and clicks on the strip and one bump, they split the strip in two and gave the clicked bump
  half of it), the ``k - g`` parts nobody clicked from the cuts; k-means
  with free centres (``"kmeans"``, the previous behaviour: k-means++ given the seeded centres) put
  them where its objective drops most, i.e. split a large part in two (PSB hand 187, tuning split:
  0.238 against 0.168 with the cuts, which follow concave creases). More clicks (``g > k``, the user
  named more parts than asked for): the whole graph is cut recursively, each cut separating clicked
  groups, until ``k`` segments, so the groups behind the weakest boundaries stay together;
  ``"kmeans"`` seeds k-means with ``k`` of the groups chosen farthest-first and ignores the others
  (PSB human 7, tuning split, 15 clicked parts for k = 6: 0.180 against 0.136 with the cuts). Chosen
  on the tuning half of the PSB meshes of the former script (split by mesh; its record:
  ``benchmarks/results/psb_segmentation_notes.md``), with ``convex_factor`` 0.2 at the time.

The shape graph (``graph``, default ``"auto"``: ``"dual"`` on a mesh, ``"vertex"`` on a point cloud):
``"vertex"`` (thesis 5.2, the literal Algorithm 4) is the vertex graph with the ``weighting``
plugin's Gaussian weights. ``"dual"`` runs the same four steps on the mesh's dual graph (faces are
the nodes, neighbours share an edge) with the concavity-aware affinities of
:func:`shape_toolkit.features.smoothing.concavity_weights` without the edge-length factor (Katz-Tal
angular distance, Lai et al.'s scale), which satisfy the chapter's only requirement on the weights,
``0 < w_ij <= 1``, and are low across concave creases, where people put part boundaries. Convex creases
leave the affinity at 1 (``convex_factor = 0``: the minima rule of Hoffman and Richards, part
boundaries along concave creases only; Lai et al. weaken convex ones too, by a factor 0.2). On the
tuning half of the PSB meshes the error fell steadily as the factor went from 0.4 to 0 (0.102, 0.077 at
0.2, 0.074 at 0.1, 0.072 at 0), so the end of that range, the rule itself, is the default rather than a
fitted value. A clicked
vertex stands for its incident face of smallest index; the labels are per face (``face_labels`` of the
returned :class:`~shape_toolkit.results.segmentation.Segmentation`; its vertex labels are those of the
largest incident area). The L-embedding of the dual graph is
computed by the algorithm (no shared spectrum is declared unless ``graph="vertex"``). The dual graph is
the default because it won on the tuning half of the PSB benchmark (25 meshes, 19 categories, one
must-link per segment: Rand index error 0.079 against 0.156 on the vertex graph, both with the first two
changes above, before ``k_mismatch``; ``benchmarks/results/psb_segmentation_notes.md``), chosen there
only; the report half of a split by category is in ``benchmarks/results/psb_segmentation.md``
(``benchmarks/configs/psb_segmentation.toml``).

Preset ``thesis``: Algorithm 4 as written, every choice above undone: the vertex graph with Gaussian
weights (eq. 3.7) and its unnormalized ``D - W`` (no mass), the ``k`` first non-null eigenpairs of ``L_hat``
(``output_dim="k"``), every edge of a cannot-link volume set *to* ``epsilon`` and of a must-link volume *to*
1 (``cannot_mode="volume"``, ``reweight="set"``), and plain k-means (k-means++ starts, ``n_init`` restarts)
on ``X_hat`` whatever the number of clicked groups (``kmeans_init="k-means++"``, ``k_mismatch="kmeans"``).

The hypersphere queries use a KD-tree on the rows of ``X``: memory stays linear in ``n``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from shape_toolkit.api.params import RANDOM_STATE, Options, Param
from shape_toolkit.core.graph import weights_from_edges
from shape_toolkit.core.shape import Shape
from shape_toolkit.core.spectrum import Spectrum
from shape_toolkit.errors import DisconnectedGraphError, ParameterError
from shape_toolkit.features.embedding import commute_time_embedding
from shape_toolkit.plugins._params import N_INIT, N_SEGMENTS, POSITIVE, POSITIVE_INT, WEIGHTING
from shape_toolkit.plugins.segmenters._bounds import CONVEX_FACTOR
from shape_toolkit.plugins.segmenters.base import BaseSegmenter, segmenter_spec
from shape_toolkit.plugins.segmenters.constraints import must_link_groups
from shape_toolkit.plugins.segmenters.embedding import laplacian_embedding_of
from shape_toolkit.plugins.segmenters.kmeans import kmeans_labels, seeded_kmeans_labels
from shape_toolkit.plugins.segmenters.n_segments import check_n_segments
from shape_toolkit.plugins.segmenters.normalized_cuts import split_by_normalized_cuts
from shape_toolkit.results.labels import coerce_constraints
from shape_toolkit.results.segmentation import Segmentation
from shape_toolkit.spectra import SpectrumSpec, build_graph
from shape_toolkit.validation import seed_of


def propagation_volumes(X: np.ndarray, pairs: np.ndarray, tree: cKDTree | None = None) -> list[np.ndarray]:
    """For each ``(i, j)`` row of ``pairs``: the sorted vertex ids whose rows of the embedding ``X``
    ``(n, p)`` lie in the ball centred at ``(x_i + x_j) / 2`` with diameter ``||x_i - x_j||`` (eq. 5.6)."""
    tree = tree if tree is not None else cKDTree(X)
    out = []
    for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
        c = 0.5 * (X[i] + X[j])
        r = 0.5 * float(np.linalg.norm(X[i] - X[j]))
        ids = np.asarray(tree.query_ball_point(c, r * (1.0 + 1e-9) + 1e-300), dtype=np.int64)
        out.append(np.unique(np.concatenate([ids, [i, j]])))
    return out


class ConstrainedSpectralClustering(BaseSegmenter):
    """CSC (Algorithm 4): constraint propagation in the commute-time embedding, modified Laplacian.

    Parameters: ``n_segments`` (``k``, required), ``n_embedding`` (``p >= k`` eigenpairs of the
    L-embedding used for propagation; None: ``max(k, 10)``), ``epsilon`` (weight inside cannot-link
    volumes), ``must_weight`` (weight inside must-link volumes, 1 in the thesis), ``weighting``
    (Gaussian, so that ``0 < w_ij <= 1``, 5.2), ``graph`` (``"auto"``, ``"vertex"`` or ``"dual"``, see
    the module doc; ``weighting`` applies to the vertex graph), ``kmeans_init`` (``"constraints"``:
    seeded by the must-link groups, or ``"k-means++"``), ``k_mismatch`` (``"ncut"`` or ``"kmeans"``:
    the rule when the number of must-link groups differs from ``k``, see the module doc),
    ``convex_factor`` (dual graph: how much a convex crease lowers an affinity; 0, the default, is the
    minima rule: only concave creases do), ``n_init``, ``random_state``.
    A given ``spectrum`` must be of the combinatorial Laplacian of the same graph (vertex graph only).

    Diagnostics: ``must_volumes_`` / ``cannot_volumes_`` (vertex counts of each propagated volume),
    ``n_must_edges_`` / ``n_cannot_edges_`` (edges re-weighted), ``modified_eigenvalues_``,
    ``n_segments_``, ``n_seed_groups_`` (must-link groups that seeded k-means), ``n_cuts_``
    (normalized cuts made by the ``k_mismatch="ncut"`` rule; 0 when it did not apply).
    """

    takes_constraints = True
    requires_n_segments = True
    split_clouds = True
    presets = {"thesis": {"graph": "vertex", "weighting": "gaussian", "output_dim": "k", "cannot_mode": "volume",
                          "reweight": "set", "must_weight": 1.0, "kmeans_init": "k-means++", "k_mismatch": "kmeans"}}

    parameter_constraints = {
        "n_segments": N_SEGMENTS,
        "n_embedding": Param(None, POSITIVE_INT, doc="eigenvectors of the embedding (None: max(k, 10))"),
        "epsilon": Param(POSITIVE, doc="weight of the graph's own edges in the modified weights"),
        "must_weight": Param(POSITIVE, doc="weight of must-link edges"),
        "weighting": WEIGHTING,
        "cannot_mode": Param(Options("bisector", "volume"), doc="how cannot-links cut the embedding"),
        "output_dim": Param(None, POSITIVE_INT, Options("k"), doc="dimension of the modified embedding (None: k - 1)"),
        "reweight": Param(Options("monotone", "set"), doc="volume edges: min/max with the old weight, or set to it"),
        "graph": Param(Options("auto", "vertex", "dual"), doc="vertex graph, dual (face) graph, or auto"),
        "kmeans_init": Param(Options("constraints", "k-means++"), doc="k-means start: from the clicks or k-means++"),
        "k_mismatch": Param(Options("ncut", "kmeans"), doc="parts when the clicked groups are not k"),
        "convex_factor": CONVEX_FACTOR,
        "n_init": N_INIT,
        "random_state": RANDOM_STATE,
    }

    def __init__(
        self,
        n_segments: int | None = None,
        *,
        n_embedding: int | None = None,
        epsilon: float = 1e-2,
        must_weight: float = 1.0,
        weighting: str = "gaussian",
        cannot_mode: str = "bisector",
        output_dim: int | None = None,
        graph: str = "auto",
        kmeans_init: str = "constraints",
        k_mismatch: str = "ncut",
        convex_factor: float = 0.0,
        n_init: int = 10,
        random_state: int = 0,
        reweight: str = "monotone",
    ):
        self.n_segments = n_segments
        self.reweight = reweight
        self.n_embedding = n_embedding
        self.epsilon = epsilon
        self.must_weight = must_weight
        self.cannot_mode = cannot_mode
        self.output_dim = output_dim
        self.weighting = weighting
        self.graph = graph
        self.kmeans_init = kmeans_init
        self.k_mismatch = k_mismatch
        self.convex_factor = convex_factor
        self.n_init = n_init
        self.random_state = random_state

    def _n_embedding(self, k: int | None) -> int:
        p = self.n_embedding if self.n_embedding is not None else max(k or 0, 10)
        return int(p)

    def spectrum_spec(self) -> SpectrumSpec | None:
        """``p + 1`` eigenpairs (``p``: ``n_embedding``, default ``max(n_segments, 10)``) of the
        combinatorial Laplacian of the ``weighting`` graph: the L-embedding of step 1. (The modified
        Laplacian of step 3 is solved by the algorithm itself.) None unless ``graph="vertex"``: the
        algorithm embeds the dual graph itself (``"auto"`` on a point cloud computes the vertex
        spectrum through the shared cache)."""
        if self._graph() != "vertex":
            return None
        k = self.n_segments if isinstance(self.n_segments, (int, np.integer)) else None
        return segmenter_spec(self._n_embedding(k) + 1, self.weighting, "combinatorial")

    def component_graph(self, shape: Shape) -> str:
        """The graph CSC clusters (:meth:`_graph`): its pieces are segmented one by one."""
        return self._graph(shape)

    def _graph(self, shape: Shape | None = None) -> str:
        """``"vertex"`` or ``"dual"`` (``"auto"``: dual for a mesh, vertex for a point cloud; ``"auto"``
        itself when no shape is given)."""
        if self.graph == "auto" and shape is not None:
            return "dual" if shape.is_mesh else "vertex"
        return self.graph

    def _node_must_links(self, shape: Shape, constraints: Any, dual: bool) -> np.ndarray:
        """The must-link pairs ``(m, 2)`` as graph nodes (faces on the dual graph, self-pairs dropped)."""
        cons = coerce_constraints(constraints, shape.n_vertices)
        if cons is None or cons.n_must == 0:
            return np.zeros((0, 2), dtype=np.int64)
        ml = self._face_of_vertex(shape)[cons.must_link] if dual else cons.must_link
        return ml[ml[:, 0] != ml[:, 1]]

    def _vertex_spectrum(self, shape: Shape, spectrum: Spectrum | None, p: int) -> Spectrum:
        """The L-embedding's spectrum on the vertex graph: the given/declared one, or (``graph="auto"``
        on a point cloud, which declares none) ``p + 1`` eigenpairs through the shared cache."""
        if self.graph == "vertex":
            return self._spectrum(shape, spectrum)
        return segmenter_spec(p + 1, self.weighting, "combinatorial").compute(shape)

    @staticmethod
    def _face_of_vertex(shape: Shape) -> np.ndarray:
        """The incident face of smallest index of every vertex (-1 for a vertex in no face)."""
        f = shape.faces
        big = np.iinfo(np.int64).max
        out = np.full(shape.n_vertices, big, dtype=np.int64)
        ids = np.arange(len(f), dtype=np.int64)
        for j in range(3):
            np.minimum.at(out, f[:, j], ids)
        out[out == big] = -1
        return out

    def _dual_graph(self, shape: Shape) -> tuple[sp.csr_matrix, Any]:
        """The dual graph's ``W`` (m, m) with concavity affinities in (0, 1], and the face standing for
        each vertex (:meth:`_face_of_vertex`)."""
        from shape_toolkit.features.smoothing import concavity_weights, dual_adjacency

        faces = shape.require_faces("CSC on the dual graph")
        pairs, w = concavity_weights(shape, convex_factor=self.convex_factor, length_weighted=False)
        return dual_adjacency(len(faces), pairs, w), self._face_of_vertex(shape)

    def modified_weights(
        self, shape: Shape, constraints: Any, *, spectrum: Spectrum | None = None
    ) -> sp.csr_matrix:
        """``W_hat`` CSR: the shape graph weights after propagating ``constraints`` (steps 1-2);
        ``(n, n)`` on the vertex graph, ``(m, m)`` on the dual graph (``graph="dual"``)."""
        dual = self._graph(shape) == "dual"
        n = shape.n_faces if dual else shape.n_vertices
        # per-vertex labels are returned: at most n_vertices segments on either graph
        k = check_n_segments(self.n_segments, min(n, shape.n_vertices), allow_none=False)
        p = self._n_embedding(k)
        if not 1 <= p <= n - 1:
            raise ParameterError(f"n_embedding must be an integer in [1, {n - 1}], got {p!r}")
        cons = coerce_constraints(constraints, shape.n_vertices)
        if dual:
            from scipy.sparse.csgraph import connected_components

            W, face_of = self._dual_graph(shape)
            n_comp, comp = connected_components(W, directed=False)
            if n_comp > 1:
                raise DisconnectedGraphError(n_comp, sorted(np.bincount(comp).tolist(), reverse=True))
            if cons is not None and len(cons):
                must, cannot = face_of[cons.must_link], face_of[cons.cannot_link]
                if (must < 0).any() or (cannot < 0).any():
                    raise ParameterError("a constrained vertex belongs to no face (graph='dual')")
                cons = type(cons)(must[must[:, 0] != must[:, 1]], cannot[cannot[:, 0] != cannot[:, 1]])
        else:
            graph = build_graph(shape, self.weighting)
            if graph.components[0] > 1:
                sizes = np.bincount(graph.components[1])
                raise DisconnectedGraphError(graph.components[0], sorted(sizes.tolist(), reverse=True))
            W = sp.csr_matrix(graph.W)
        self.must_volumes_, self.cannot_volumes_ = [], []
        self.n_must_edges_ = self.n_cannot_edges_ = 0
        if cons is None or len(cons) == 0:
            return W
        if dual:
            vals, vecs = laplacian_embedding_of(W, p)
            X = vecs / np.sqrt(vals)[None, :]
        else:
            X = commute_time_embedding(self._vertex_spectrum(shape, spectrum, p), p)
        tree = cKDTree(X)
        up = sp.triu(W, k=1).tocoo()
        ei, ej, w = up.row.astype(np.int64), up.col.astype(np.int64), up.data.copy()
        inside = np.zeros(n, dtype=bool)
        side = np.zeros(n, dtype=bool)
        for pairs, value, sizes, attr, cannot in (
            (cons.must_link, self.must_weight, self.must_volumes_, "n_must_edges_", False),
            (cons.cannot_link, self.epsilon, self.cannot_volumes_, "n_cannot_edges_", True),
        ):
            touched = np.zeros(len(w), dtype=bool)
            for (i, j), ids in zip(pairs.tolist(), propagation_volumes(X, pairs, tree)):
                inside[:] = False
                inside[ids] = True
                sel = inside[ei] & inside[ej]
                if cannot and self.cannot_mode == "bisector":
                    side[:] = False
                    side[ids] = (X[ids] - 0.5 * (X[i] + X[j])) @ (X[j] - X[i]) > 0
                    sel &= side[ei] != side[ej]
                if self.reweight == "set":  # the thesis: w_ij = epsilon (cannot) or 1 (must)
                    w[sel] = value
                else:  # monotone: a cannot-link never raises an affinity, a must-link never lowers one
                    w[sel] = np.minimum(w[sel], value) if cannot else np.maximum(w[sel], value)
                touched |= sel
                sizes.append(int(len(ids)))
            setattr(self, attr, int(touched.sum()))
        return weights_from_edges(n, np.stack([ei, ej], axis=1), w)

    def _segment(self, shape: Shape, *, spectrum: Spectrum | None, constraints: Any) -> Segmentation:
        """The segmentation of a shape of one piece; with ``graph="dual"`` the clustering is per face."""
        dual = self._graph(shape) == "dual"
        n = shape.n_faces if dual else shape.n_vertices
        # per-vertex labels are returned: at most n_vertices segments on either graph
        k = check_n_segments(self.n_segments, min(n, shape.n_vertices), allow_none=False)
        seed = seed_of(self.random_state)
        dim = k - 1 if self.output_dim is None else (k if self.output_dim == "k" else self.output_dim)
        if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or not 1 <= dim <= n - 1:
            raise ParameterError(f"output_dim must be an integer in [1, {n - 1}], got {dim!r}")
        W_hat = self.modified_weights(shape, constraints, spectrum=spectrum)
        vals, vecs = laplacian_embedding_of(W_hat, int(dim))
        if np.any(vals <= 1e-12 * max(abs(vals).max(), 1e-300)):
            raise ParameterError("the modified graph is disconnected (a zero non-null eigenvalue)")
        X_hat = vecs / np.sqrt(vals)[None, :]
        groups = must_link_groups(self._node_must_links(shape, constraints, dual))
        g, labels = len(groups), None
        self.n_cuts_ = 0
        if self.kmeans_init == "constraints" and self.k_mismatch == "ncut" and 2 <= g != k:
            # fewer clicked parts than k: the g clicked segments, then cuts; more: cuts between groups
            start = (seeded_kmeans_labels(X_hat, g, groups, seed, self.n_init) if g < k
                     else np.zeros(n, dtype=np.int64))
            cut, values = split_by_normalized_cuts(W_hat, start, k, groups=groups)
            if cut.max() + 1 == k:
                labels, self.n_cuts_ = cut, len(values)
        if labels is None and self.kmeans_init == "constraints" and groups:
            labels = seeded_kmeans_labels(X_hat, k, groups, seed, self.n_init)
        elif labels is None:
            labels = kmeans_labels(X_hat, k, seed, self.n_init)
        self.n_seed_groups_ = len(groups)
        self.modified_eigenvalues_ = vals.tolist()
        self.n_segments_ = int(labels.max() + 1)
        return Segmentation.of_faces(shape, labels) if dual else Segmentation.of_vertices(shape, labels)
