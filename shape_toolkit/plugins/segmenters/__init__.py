"""shape_toolkit.plugins.segmenters."""
