"""One module per `uwbcal` subcommand.

Each module defines ``register(subparsers)`` which adds its parser and sets
``func=<callable(args) -> int>`` as the parser default. The CLI discovers the modules, so a
new command is one new file. Import heavy libraries (matplotlib, scipy) inside the command
function, not at module level, so that `uwbcal --help` stays fast.
"""
