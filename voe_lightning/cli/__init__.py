"""The command line (``python -m voe_lightning``, the ``voe-lightning`` script), which parses,
checks and dispatches: the entry point and its LightningCLI (``app``), the subcommands in its
parser (``commands``), the run-wide arguments (``run_arguments``), arguments checked against each
other before any work (``preflight``) and bad input as one line (``user_errors``,
``parser_errors``). What it runs is the package's: the analyses (``voe_lightning.analysis``), a
run's folders and checkpoint arguments (``run_folders``, ``checkpoint_arguments``), ``migrate``'s
rewrite (``migration``). The entry point's public names are re-exported here:
``voe_lightning.cli:main`` is the installed script."""

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
