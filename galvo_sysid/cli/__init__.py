"""The ``galvo-sysid`` command-line tool.

One module per subcommand (``add_parser`` and ``run``), what they share once in ``common``;
``main`` builds the parser and runs the command.
"""
