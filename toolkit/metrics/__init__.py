"""Evaluation metrics: keypoint repeatability, segmentation scores, correspondence errors.

Each area lives in its own submodule and is re-exported here.
"""
from .correspondence import *  # noqa: F401,F403
from .keypoints import *  # noqa: F401,F403
from .segmentation import *  # noqa: F401,F403
