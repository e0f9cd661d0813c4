"""Command-line front end: one module per subcommand, each with ``register(subparsers)``."""
