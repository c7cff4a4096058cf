"""Evaluation metrics: keypoint repeatability, segmentation scores, correspondence errors.

Each area lives in its own submodule and is re-exported here.
"""
from shape_toolkit.metrics.correspondence import *  # noqa: F401,F403
from shape_toolkit.metrics.keypoints import *  # noqa: F401,F403
from shape_toolkit.metrics.segmentation import *  # noqa: F401,F403
