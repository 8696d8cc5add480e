"""Command-line interface: argument parsing and wiring only."""
