"""The ``galvo-sysid`` command-line tool.

One module per subcommand group; ``main`` builds the parser.
"""
