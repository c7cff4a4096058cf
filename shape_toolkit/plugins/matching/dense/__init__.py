"""shape_toolkit.plugins.matching.dense."""
