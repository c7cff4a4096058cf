"""shape_toolkit.plugins.descriptors."""
