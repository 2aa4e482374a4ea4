"""Global planners built on the fabric."""
