"""The command line (``python -m voe_lightning``, the ``voe-lightning`` script): the entry point
and its LightningCLI (``app``), the subcommands in its parser (``commands``), the run-wide
arguments (``run_arguments``), the model arguments matched with a checkpoint's
(``checkpoint_arguments``), the run folder a checkpoint's run works in (``run_folders``), bad
input as one line (``user_errors``), and what only the command line uses: checks before any
work (``preflight``), analyses across runs (``analysis``, the ``analyze`` subcommands), the
untrained null model (``null``), the training-set-size sweep (``size_sweep``) and the one-off
rewrite of a run saved under old class paths (``migrate``). The entry point's public names are
re-exported here: ``voe_lightning.cli:main`` is the installed script."""

from voe_lightning.cli.app import NOT_CAUSAL_EXIT, VOECLI, main
from voe_lightning.cli.commands import LIGHTNING_SUBCOMMANDS
from voe_lightning.cli.run_arguments import BASE_CONFIG, base_alpha
from voe_lightning.cli.user_errors import DEBUG_VARIABLE, USER_ERRORS

__all__ = [
    "main",
    "VOECLI",
    "BASE_CONFIG",
    "DEBUG_VARIABLE",
    "LIGHTNING_SUBCOMMANDS",
    "NOT_CAUSAL_EXIT",
    "USER_ERRORS",
    "base_alpha",
]
