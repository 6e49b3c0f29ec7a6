"""The shipped configs as the CLI composes them (``--print_config``: no data, no training); their
paths are relative to the repository root, which the caller makes the working folder."""

import contextlib
import io
from functools import cache

import pytest
import yaml

from voe_lightning.cli import main


@cache
def parsed(*arguments: str) -> dict:
    """The full config that ``python -m voe_lightning ARGUMENTS`` would run, as a dict."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed), pytest.raises(SystemExit) as exit_:
        main([*arguments, "--print_config"])
    assert exit_.value.code in (None, 0), f"{' '.join(arguments)} does not parse"
    return yaml.safe_load(printed.getvalue())


def compose(*names: str, subcommand: str = "fit") -> dict:
    """The parsed config of ``--config configs/NAME.yaml`` for each name, in order."""
    return parsed(
        subcommand, *(word for name in names for word in ("--config", f"configs/{name}.yaml"))
    )
