"""shape_toolkit.plugins.weightings."""
