"""Applications on top of the library: the CLI, the demo, bag analysis and simulation."""
