"""`gsgs` subcommands, one module each: `add_arguments(parser)` and `run(args) -> int`; gsgs_engine.cli dispatches."""
