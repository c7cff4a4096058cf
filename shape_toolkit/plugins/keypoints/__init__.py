"""shape_toolkit.plugins.keypoints."""
