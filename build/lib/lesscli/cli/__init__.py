"""Command-line interface: one module per subcommand, loaded lazily (see registry.py)."""
