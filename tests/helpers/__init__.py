"""Shared test helpers: a refused command's one error line, a few pair results, the tests' alpha."""

import numpy as np
import pytest

from voe_lightning.cli import main
from voe_lightning.report.pairs import PairResults
from voe_lightning.runs import base_alpha


def error_line(capsys) -> str:
    """The one line a refused command printed (and that it printed no traceback)."""
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, err
    return lines[0]


def refused(capsys, arguments: list[str]) -> str:
    with pytest.raises(SystemExit) as raised:
        main(arguments)
    assert raised.value.code == 2
    return error_line(capsys)


def pair_results(pairs: int = 4) -> PairResults:
    rng = np.random.default_rng(0)
    return PairResults(
        concept=["continuity"] * pairs,
        variant=["standard"] * pairs,
        seed=np.arange(pairs),
        manipulation_frame=np.full(pairs, 2),
        surprise_consistent=rng.random((pairs, 5)),
        surprise_inconsistent=rng.random((pairs, 5)) + 0.1,
    )


#: The significance level every test here tests at: the run's, as configs/base.yaml sets it.
ALPHA = base_alpha()
