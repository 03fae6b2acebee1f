"""The ``sclam`` command, one module per subcommand: parse, call, print; no numerics.
May import every layer."""
