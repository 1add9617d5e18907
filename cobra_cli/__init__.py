"""The ``cobra`` command line: one subcommand per module ``cobra_cli.cmd_<name>``."""
