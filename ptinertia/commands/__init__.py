"""One module per subcommand: ``add_parser(subparsers, name, help_text)`` and ``run(args) -> int``."""
