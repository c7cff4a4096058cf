"""Parameter declarations shared by several plugins (:mod:`shape_toolkit.api.params`)."""

from __future__ import annotations

from shape_toolkit.api.params import InstanceOf, Interval, ListOf, Options, Param, PluginRef
from shape_toolkit.core.spectrum import LAPLACIANS

#: the weighting plugin of the graph whose spectrum a plugin declares
WEIGHTING = Param(str, doc="weighting plugin of the graph (its name, see plugins list)")
#: the Laplacian of that spectrum
LAPLACIAN = Param(Options(*LAPLACIANS), doc="Laplacian of the declared spectrum")
#: a count of at least one (iterations, rings, eigenpairs, samples, ...)
POSITIVE_INT = Interval(int, 1)
#: a positive finite number
POSITIVE = Interval(float, 0, None, closed="neither")
#: a finite number >= 0
NON_NEGATIVE = Interval(float, 0)
#: a fraction in [0, 1]
FRACTION = Interval(float, 0, 1)
#: diffusion times: one number >= 0 or a list of them (t = 0, the identity kernel, is in the thesis's tables)
TIMES = (NON_NEGATIVE, ListOf(NON_NEGATIVE))

#: the consistency kernel's width: unit-sphere heat distances lie in [0, pi] and their differences carry the
#: rounding of arccos, ~sqrt(eps) = 1.5e-8 radians, so a narrower kernel measures rounding (and sigma^2 underflows
#: towards 1e-154); above 1e8, Delta^2 / (2 sigma^2) <= 5e-16 is below eps and every weight is exactly 1
SIGMA = Param(Interval(float, 1e-8, 1e8), doc="width of the pairwise consistency kernel in radians of unit-sphere "
              "heat distance (in [1e-8, 1e8]: distances lie in [0, pi] with rounding ~1.5e-8; from 1e8 on every "
              "weight is exactly 1, as for any larger sigma, which would only overflow sigma^2)")
#: the heat kernels' diffusion time (t lambda_k must stay finite)
TIME = Param(None, Interval(float, 0, 1e100, closed="right"), doc="diffusion time of the heat-kernel affinities "
             "(None: from the spectrum; at most 1e100: once t lambda_1 > 745 every non-constant term exp(-t lambda) "
             "is 0 in float64, so larger times change nothing unless lambda_1 < 1e-97, while t lambda_k must stay "
             "finite, below 1.8e308)")
#: the association-graph matchers (replicator, spectral, rrwm; umeyama shares k, time, sigma)
ASSOCIATION = {
    "k": Param(POSITIVE_INT, doc="non-null eigenpairs of the heat kernel"),
    "time": TIME,
    "sigma": SIGMA,
    "adf_ratio": Param(Interval(float, 1, None, closed="neither"), doc="max ratio of two candidates' ADF values"),
    "max_candidates": Param(POSITIVE_INT, doc="target candidates per source keypoint"),
    "min_score": Param(FRACTION, doc="drop matches scoring below this fraction of the best"),
    "orientation": Param(Options("preserving", "reversing", "none"), doc="side of each match (meshes)"),
    "spectrum": Param(Options("lbo", "graph"), doc="heat-kernel spectrum: cotangent LBO, or Gaussian graph D - W"),
}

#: the descriptor a matcher computes on both shapes: a name, a {plugin, preset, params} table or an object
TABLE = InstanceOf(dict, name="table")
DESCRIPTOR = Param(PluginRef("descriptors"), TABLE, doc="descriptor plugin computed on both shapes")
#: parameters of a descriptor given by name
DESCRIPTOR_PARAMS = Param(None, TABLE, doc="parameters of the descriptor given by name")
#: which side of a symmetric shape a map keeps
ORIENTATION = Param(Options("preserving", "reversing", "none"), doc="orientation the map keeps (meshes)")

#: the number of segments of a segmenter
N_SEGMENTS = Param(None, Interval(int, 2), doc="number of segments (None: chosen by the method, where it can)")
#: restarts of k-means / GMM
N_INIT = Param(
    Interval(int, 1, 1000),
    doc="restarts of the clustering (the best is kept); <= 1000, 100x scikit-learn's 10: each restart is a "
        "full fit (time grows linearly) while the chance that one more restart beats the best so far falls as 1/n",
)
