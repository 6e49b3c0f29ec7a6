"""The untrained null (voe_lightning.null, ``analyze null``): its table by hand from synthetic
summaries, and the command at a tiny size: each initialization its own seed and report, a
trained report placed in the distribution."""

import json
from pathlib import Path

import pytest

from voe_lightning.cli import main
from voe_lightning.null import format_null, null_rows

TINY = str(Path(__file__).parent / "configs" / "tiny.yaml")


def summary(t_standard, t_pooled, voe, significant=False):
    rows = [{"concept": "solidity", "variant": "standard", "t": t_standard,
             "significant": significant},
            {"concept": "solidity", "variant": "pooled", "t": t_pooled, "significant": False},
            {"concept": "solidity", "variant": "generalization", "t": None,
             "significant": None}]
    return {"alpha": 0.01, "rows": rows, "verdicts": [{"concept": "solidity", "voe": voe}]}


def test_null_rows_by_hand():
    summaries = [summary(1.0, 0.5, False), summary(3.0, "inf", True, significant=True),
                 summary(-2.0, 0.0, False), summary(3.0, 1.0, False)]
    trained = summary(3.0, 9.0, True)
    standard, pooled = null_rows(summaries, trained)
    assert (standard["variant"], standard["initializations"]) == ("standard", 4)
    assert (standard["t_median"], standard["t_min"], standard["t_max"]) == (2.0, -2.0, 3.0)
    assert standard["significant_share"] == 0.25 and standard["voe_share"] == 0.25
    # trained t 3.0 over null {1, 3, -2, 3}: two below, two tied -> (2 + 1) / 4
    assert standard["trained_percentile"] == 75.0
    assert pooled["t_max"] == float("inf") and pooled["trained_percentile"] == 75.0
    table = format_null([standard, pooled], 0.01)
    assert "| solidity | standard | 4 | +2.00 [-2.00, +3.00] | 25% | 25% | +3.00 | 75 |" in table
    assert "p < 0.01" in table


def test_analyze_null_tests_each_initialization_on_the_same_probes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main(["test", "--config", TINY, "--model", "voe_lightning.model.CueScorer",
          "--model.init_args.cue", "motion", "--trainer.enable_progress_bar", "false"])
    trained = tmp_path / "runs" / "tiny" / "version_0" / "voe_report"
    table = main(["analyze", "null", "--configs", f"[{TINY}]", "--seeds", "2",
                  "--out", str(tmp_path / "null"), "--trained", str(trained),
                  "--extra_args", '["--trainer.enable_progress_bar", "false"]'])
    document = json.loads((tmp_path / "null" / "null.json").read_text())
    assert [i["seed"] for i in document["initializations"]] == [0, 1]
    first, second = ([row["t"] for row in i["rows"]] for i in document["initializations"])
    assert first != second  # two initializations of the network, not one
    assert all((tmp_path / "null" / f"seed_{s}" / "version_0" / "voe_report" / "summary.json")
               .is_file() for s in (0, 1))
    assert table == (tmp_path / "null" / "null.md").read_text()
    assert all(row["initializations"] == 2 and "trained_percentile" in row
               for row in document["rows"])
    with pytest.raises(SystemExit):
        main(["analyze", "null", "--configs", f"[{TINY}]", "--seeds", "0"])
