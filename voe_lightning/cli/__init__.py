"""The command line (``python -m voe_lightning``, the ``voe-lightning`` script): the entry point
and its LightningCLI (``app``), the subcommands in its parser (``commands``), the run-wide
arguments (``run_arguments``), the model arguments matched with a checkpoint's
(``checkpoint_arguments``), the run folder a checkpoint's run works in (``run_folders``), bad
input as one line (``user_errors``), checks before any work (``preflight``) and the one-off
rewrite of a run saved under old class paths (``migrate``). It parses, checks and dispatches:
the analyses it runs (``analyze``) are ``voe_lightning.analysis``'s. The entry point's public
names are re-exported here: ``voe_lightning.cli:main`` is the installed script."""

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
