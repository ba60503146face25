"""rvis application layer: configuration, the `rvis` command line, the in-line cycle,
persistence and the operator UI. The only layer that wires devices to algorithms."""
