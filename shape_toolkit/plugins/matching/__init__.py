"""shape_toolkit.plugins.matching."""
