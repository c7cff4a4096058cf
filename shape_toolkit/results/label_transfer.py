"""Probabilistic label transfer (thesis Algorithm 5, section 5.4).

The labels of a segmented training shape are carried to a test shape through a soft
assignment: with EM posteriors ``p_ij = P(z_i = j | x_i^test)`` of test vertex ``i`` to train
vertex ``j`` and the training labels as hard assignments ``delta_jl`` (eq. 5.8), the test vertex
takes ``argmax_l sum_j p_ij delta_jl`` (eq. 5.7, 5.9). The default matcher is the one of the
thesis: eigenvector alignment + EM registration (``eigvec-alignment``; its preset ``thesis`` aligns by
histograms as the text, its default searches, see that module); with seeds,
``em-registration``. A matcher without posteriors is run test -> train and its hard map is used.
Large shapes go through proxies: :func:`~shape_toolkit.plugins.matching.multires.transfer_labels_through_proxies`
(``shape-toolkit transfer-labels`` does above 1.5 ``--proxy`` vertices).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shape_toolkit.core.shape import Shape
from shape_toolkit.errors import ParameterError
from shape_toolkit.results.correspondence import Correspondence, transfer_labels
from shape_toolkit.validation import check_seeds, first_per_source

__all__ = ["probabilistic_label_transfer", "check_train_labels"]


def check_train_labels(train: Shape, train_labels: np.ndarray) -> np.ndarray:
    """``train_labels`` as an integer array ``(n_train,)`` with at least one labelled (``>= 0``) vertex of ``train``,
    else a :class:`ParameterError` saying what is wrong."""
    lab = np.asarray(train_labels)
    if lab.shape != (train.n_vertices,):
        raise ParameterError(
            f"train labels must have one entry per train vertex ({train.n_vertices}), got {lab.shape}"
        )
    if lab.size and not np.issubdtype(lab.dtype, np.integer):
        raise ParameterError("train labels must be integers")
    if not np.any(lab >= 0):
        raise ParameterError("the train shape has no labelled vertex")
    return lab


def probabilistic_label_transfer(
    train: Shape,
    train_labels: np.ndarray,
    test: Shape,
    *,
    matcher: str = "eigvec-alignment",
    matcher_params: dict[str, Any] | None = None,
    preset: str | None = None,
    seeds: np.ndarray | None = None,
) -> tuple[np.ndarray, Correspondence]:
    """Labels ``(n_test,)`` int64 of ``test`` from ``train_labels`` ``(n_train,)`` and the
    correspondence used (train -> test with posteriors, or test -> train for hard matchers).
    ``seeds`` are ``[train, test]`` vertex pairs."""
    from shape_toolkit.api.registry import create_plugin

    lab = check_train_labels(train, train_labels)
    m = create_plugin("dense_matchers", matcher, preset, **(matcher_params or {}))
    corr = m.match(train, test, seeds=seeds)
    if corr.posteriors is not None:
        return transfer_labels(corr, lab, to="target", soft=True), corr
    rev = None
    if seeds is not None:  # reversed: a test vertex two train vertices were seeded to keeps the first of them
        rev = first_per_source(check_seeds(seeds, train.n_vertices, test.n_vertices)[:, ::-1])
    corr = m.match(test, train, seeds=rev)
    return transfer_labels(corr, lab, to="source"), corr
