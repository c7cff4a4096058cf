"""Evaluation metrics: keypoint repeatability, segmentation scores, correspondence errors.

Each area lives in its own submodule and is re-exported here.
"""
