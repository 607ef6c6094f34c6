"""One help formatter for every command-line tool of quad_il (issue 31: `--help` lists every option with its
default)."""

from __future__ import annotations

import argparse


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """The description as written (usage examples keep their lines) and "(default: X)" after every option.

    argparse adds the default only to an option that has help text, so every option of a quad_il tool has
    one (tests/python/test_cli_help.py checks it). A help text that already says its default in words
    ("(default: a temporary directory)", for an option whose value None means that) is left as it is.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.help and "(default" in action.help:
            return action.help
        return super()._get_help_string(action)
