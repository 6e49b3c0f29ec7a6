"""The command line (``python -m voe_lightning``, the ``voe-lightning`` script): the entry point
and its parser (``app``), and what only the command line uses: checks before any work
(``preflight``), analyses across runs (``analysis``, the ``analyze`` subcommands), the untrained
null model (``null``) and the training-set-size sweep (``size_sweep``). The entry point's public
names are re-exported here: ``voe_lightning.cli:main`` is the installed script."""

from voe_lightning.cli.app import (
    BASE_CONFIG,
    DEBUG_VARIABLE,
    LIGHTNING_SUBCOMMANDS,
    NOT_CAUSAL_EXIT,
    USER_ERRORS,
    VOECLI,
    base_alpha,
    main,
)

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
