"""shape_toolkit.plugins.matching.sparse."""
