"""Subcommands of the `changing-slam` CLI: argument parsing and printing only."""
