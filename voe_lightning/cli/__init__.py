"""The command line (``python -m voe_lightning``; ``voe_lightning.cli:main``, the installed script)
only parses, checks and dispatches: the entry point (``app``), the subcommands (``commands``),
run-wide arguments (``run_arguments``), checks before any work (``preflight``) and bad input as one
line (``user_errors``, ``parser_errors``). What it runs is the package's own."""

from voe_lightning.cli.app import NOT_CAUSAL_EXIT, VOECLI, main
from voe_lightning.cli.commands import LIGHTNING_SUBCOMMANDS
from voe_lightning.cli.user_errors import DEBUG_VARIABLE, USER_ERRORS

__all__ = [
    "main",
    "VOECLI",
    "DEBUG_VARIABLE",
    "LIGHTNING_SUBCOMMANDS",
    "NOT_CAUSAL_EXIT",
    "USER_ERRORS",
]
