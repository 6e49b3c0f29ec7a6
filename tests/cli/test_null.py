"""The untrained null (voe_lightning.analysis.null, ``analyze null``): its table by hand from synthetic
summaries, and the command at a tiny size: each initialization its own seed and report, a
trained report placed in the distribution; the positive control's test report carrying its
priors alone (one initialization of its own config); ``--noise`` making a zero-heads family's
one function N distinct, reproducibly."""

import json
import math
from pathlib import Path

import pytest
import scipy.stats
import torch
import yaml
from helpers.locations import REPO, TINY_CONFIG
from PIL import Image

from voe_lightning.analysis.init_noise import add_noise, noise_unit
from voe_lightning.analysis.null import format_null, null_figure, null_rows
from voe_lightning.cli import main

TINY = TINY_CONFIG


def summary(t_standard, t_pooled, voe, significant=False):
    rows = [
        {"concept": "solidity", "variant": "standard", "t": t_standard, "significant": significant},
        {"concept": "solidity", "variant": "pooled", "t": t_pooled, "significant": False},
        {"concept": "solidity", "variant": "generalization", "t": None, "significant": None},
    ]
    return {"alpha": 0.01, "rows": rows, "verdicts": [{"concept": "solidity", "voe": voe}]}


def test_null_rows_by_hand():
    summaries = [
        summary(1.0, 0.5, False),
        summary(3.0, "inf", True, significant=True),
        summary(-2.0, 0.0, False),
        summary(3.0, 1.0, False),
    ]
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


def test_an_undefined_t_is_counted_and_left_out_of_the_spread():
    """An initialization whose every difference is 0 has no t (NaN): the spread and the
    percentile are over the others, and the table says how many were undefined."""
    summaries = [
        summary(1.0, 0.5, False),
        summary(float("nan"), 0.5, False),
        summary(3.0, 0.5, True),
    ]
    standard, _ = null_rows(summaries, summary(2.0, 0.5, True))
    assert (standard["initializations"], standard["undefined"]) == (3, 1)
    assert (standard["t_median"], standard["t_min"], standard["t_max"]) == (2.0, 1.0, 3.0)
    assert standard["trained_percentile"] == 50.0  # 2.0 over {1, 3}
    assert "| 3 | +2.00 [+1.00, +3.00], 1 undefined | 0% | 33% |" in format_null([standard], 0.01)


def test_the_null_figure_draws_each_t_against_the_critical_t():
    """A row per concept/variant: the finite untrained t's as points, the critical t of the
    row's df at alpha (scipy's) as the dashed mark, the trained t as the one diamond."""
    summaries = [
        summary(1.0, 0.5, False),
        summary(3.0, "inf", True, significant=True),
        summary(-2.0, 0.0, False),
    ]
    for row in (row for each in summaries for row in each["rows"]):
        row["df"] = 9 if row["variant"] == "standard" else 17.5
    document = {
        "configs": ["configs/object_state.yaml"],
        "seeds": 3,
        "rows": null_rows(summaries, summary(4.0, 2.5, True)),
        "initializations": [{"seed": seed, "rows": s["rows"]} for seed, s in enumerate(summaries)],
    }
    [ax] = null_figure(document, 0.01).axes
    points = [collection.get_offsets() for collection in ax.collections]
    standard, trained_standard, pooled, trained_pooled = points
    assert sorted(standard[:, 0]) == [-2.0, 1.0, 3.0] and abs(standard[:, 1]).max() <= 0.2
    assert sorted(pooled[:, 0]) == [0.0, 0.5]  # the infinite t left out
    assert trained_standard.tolist() == [[4.0, 0.0]] and trained_pooled.tolist() == [[2.5, 1.0]]
    critical = [line.get_xdata()[0] for line in ax.lines if line.get_linestyle() == "--"]
    assert critical == pytest.approx([scipy.stats.t.ppf(0.99, 9), scipy.stats.t.ppf(0.99, 17.5)])
    assert [label.get_text() for label in ax.get_yticklabels()] == [
        "solidity / standard",
        "solidity / pooled",
    ]


def analyze_two_seeds(tmp_path: Path, extra_args: list[str]) -> str:
    """``analyze null`` of the tiny config at seeds 0 and 1 into tmp_path/null, placing the
    tiny run tested first; its table."""
    return main(
        [
            "analyze",
            "null",
            "--configs",
            f"[{TINY}]",
            "--seeds",
            "2",
            "--out",
            str(tmp_path / "null"),
            "--trained",
            str(tmp_path / "runs" / "tiny" / "version_0" / "voe_report"),
            "--extra_args",
            json.dumps(extra_args),
        ]
    )


def test_analyze_null_tests_each_initialization_on_the_same_probes(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    main(
        [
            "test",
            "--config",
            TINY,
            "--model",
            "voe_lightning.model.CueScorer",
            "--model.init_args.cue",
            "motion",
            "--trainer.enable_progress_bar",
            "false",
        ]
    )
    trained = tmp_path / "runs" / "tiny" / "version_0" / "voe_report"
    table = analyze_two_seeds(tmp_path, ["--trainer.enable_progress_bar", "false"])
    document = json.loads((tmp_path / "null" / "null.json").read_text())
    assert [i["seed"] for i in document["initializations"]] == [0, 1]
    first, second = ([row["t"] for row in i["rows"]] for i in document["initializations"])
    assert first != second  # two initializations of the network, not one
    assert all(
        (tmp_path / "null" / f"seed_{s}" / "version_0" / "voe_report" / "summary.json").is_file()
        for s in (0, 1)
    )
    assert table == (tmp_path / "null" / "null.md").read_text()
    figure = tmp_path / "null" / "null.png"
    assert f"wrote {figure}" in capsys.readouterr().out
    with Image.open(figure) as image:
        assert image.format == "PNG" and 500 <= image.width <= 2000 and 200 <= image.height <= 2000
    assert 10_000 < figure.stat().st_size < 1_000_000
    assert "priors_alone" not in json.loads((trained / "summary.json").read_text())  # not asked
    assert all(
        row["initializations"] == 2 and "trained_percentile" in row for row in document["rows"]
    )
    assert document["distinct_functions"] == 2 and "2 of 2 initializations are different" in table
    with pytest.raises(SystemExit):
        main(["analyze", "null", "--configs", f"[{TINY}]", "--seeds", "0"])


def test_a_null_whose_initializations_are_one_function_says_it_tests_nothing(
    tmp_path, monkeypatch, capsys
):
    """Issue 70: a family whose every draw is the same function (here a follower, which has
    no parameters; the zero-heads learner is another) is named, and a trained t gets no
    percentile among copies of one value."""
    monkeypatch.chdir(tmp_path)
    follower = ["--model", "voe_lightning.model.ObjectFollower", "--trainer.enable_progress_bar"]
    main(["test", "--config", TINY, *follower, "false"])
    table = analyze_two_seeds(tmp_path, [*follower, "false"])
    document = json.loads((tmp_path / "null" / "null.json").read_text())
    assert document["distinct_functions"] == 1 and "redrawn_with_noise" not in document
    assert "they are one function, and this null tests nothing** (the model has no learned" in table
    assert all(row["trained_percentile"] is None for row in document["rows"] if "trained_t" in row)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["analyze", "null", "--configs", f"[{TINY}]", "--seeds", "2", "--noise", "1",
              "--extra_args", json.dumps([*follower, "false"])])  # fmt: skip
    assert "--noise 1 changes nothing: ObjectFollower has no learned" in capsys.readouterr().err


def test_noise_is_each_tensors_own_scale_seeded_and_spares_frozen_parameters():
    """``add_noise``: a drawn tensor's unit is its own sd, a zeroed one's 1/sqrt(3 fan-in) (a
    bias its layer's weight's), a frozen tensor is kept; the same seed gives the same model,
    another seed another."""

    def zeroed(layer: torch.nn.Linear) -> torch.nn.Linear:
        for tensor in (layer.weight, layer.bias):
            torch.nn.init.zeros_(tensor)
        return layer

    def network(seed: int) -> torch.nn.Sequential:
        torch.manual_seed(0)  # every seed builds the same network: the head at zero
        model = torch.nn.Sequential(torch.nn.Linear(4, 8), zeroed(torch.nn.Linear(8, 3)))
        model[0].bias.requires_grad_(False)
        add_noise(model, 0.5, seed)
        return model

    drawn, head = torch.nn.Linear(4, 8), zeroed(torch.nn.Linear(8, 3))
    assert noise_unit(drawn, drawn.weight) == pytest.approx(float(drawn.weight.std(correction=0)))
    assert noise_unit(head, head.weight) == noise_unit(head, head.bias) == 1 / math.sqrt(24)
    one, again, other = network(0), network(0), network(1)
    assert all(torch.equal(a, b) for a, b in zip(one.parameters(), again.parameters()))
    assert not torch.equal(one[1].weight, other[1].weight) and one[1].weight.abs().min() > 0
    assert torch.equal(one[0].bias, other[0].bias)  # frozen: given, not drawn
    assert float(torch.cat([one[1].weight.flatten(), other[1].weight.flatten()]).std()) == (
        pytest.approx(0.5 / math.sqrt(24), rel=0.5)
    )


def zero_heads_config(folder: Path) -> str:
    """The tiny run with configs/oracle_states_15min.yaml's model (every predicting layer
    started at zero, small sizes) and configs/overlays/untrained_null.yaml: its path."""
    model = yaml.safe_load((REPO / "configs" / "oracle_states_15min.yaml").read_text())["model"]
    model["init_args"].update(hidden_size=16, message_size=8, withhold_frames=2)
    overlay = yaml.safe_load((REPO / "configs" / "overlays" / "untrained_null.yaml").read_text())
    config = {**yaml.safe_load(Path(TINY).read_text()), "model": model}
    config["trainer"]["callbacks"] = overlay["trainer"]["callbacks"]
    config["data"]["init_args"].update(overlay["data"]["init_args"])
    path = folder / "zero_heads.yaml"
    path.write_text(yaml.safe_dump(config))
    return str(path)


def test_noise_makes_a_one_function_null_distinct_and_reproducible(tmp_path, monkeypatch):
    """Issue 70's "nulls that test": the zero-heads learner's untrained draws are one function,
    so the null draws them again with noise 1 and says why; with noise they are N of N
    distinct, the noise in null.json and the table; the same seed and noise give the same
    pairs.csv again."""
    monkeypatch.chdir(tmp_path)
    config = zero_heads_config(tmp_path)

    def null(out: str, seeds: int, noise: float) -> tuple[str, dict]:
        table = main(
            ["analyze", "null", "--configs", f"[{config}]", "--seeds", str(seeds)]
            + ["--out", out, "--noise", str(noise)]
            + ["--extra_args", '["--trainer.enable_progress_bar", "false"]']
        )
        return table, json.loads((tmp_path / out / "null.json").read_text())

    table, document = null("plain", 2, 0)
    assert document["distinct_functions"] == 2 and document["noise"] == 1.0
    assert document["redrawn_with_noise"] and "this null tests nothing" not in table
    assert "Without noise the 2 initializations scored every pair alike: one function" in table
    table, document = null("noisy", 2, 1.0)
    assert "redrawn_with_noise" not in document and "Without noise" not in table
    assert document["distinct_functions"] == 2 and document["noise"] == 1.0
    assert "2 of 2 initializations are different functions" in table
    assert "Untrained initializations of one config, each with noise 1 (--noise: " in table
    null("again", 1, 1.0)
    pairs = [
        tmp_path / out / "seed_0" / "version_0" / "voe_report" / "pairs.csv"
        for out in ("noisy", "again", "plain/noise_1", "plain")
    ]
    assert pairs[0].read_bytes() == pairs[1].read_bytes() == pairs[2].read_bytes()
    assert pairs[0].read_bytes() != pairs[3].read_bytes()  # the plain draw, without noise


def control_config(folder: Path) -> str:
    """The tiny run with configs/object_state.yaml's model (its priors as given, small sizes)
    and callbacks (the report's priors_alone among them): its path."""
    control = yaml.safe_load((REPO / "configs" / "object_state.yaml").read_text())
    config = yaml.safe_load(Path(TINY).read_text())
    config["model"] = control["model"]
    config["model"]["init_args"].update(hidden_size=16, message_size=8, withhold_frames=2)
    config["trainer"]["callbacks"] = control["trainer"]["callbacks"]
    path = folder / "control.yaml"
    path.write_text(yaml.safe_dump(config))
    return str(path)


@pytest.mark.slow
def test_the_controls_report_carries_its_priors_alone(tmp_path, monkeypatch, capsys):
    """A tested control checkpoint's summary.json and summary.md hold, labelled, the t and
    verdicts of the same config untrained at the run's seed: exactly what ``analyze null``
    finds for that initialization, and not the trained model's."""
    monkeypatch.chdir(tmp_path)
    config = control_config(tmp_path)
    main(["fit", "--config", config])
    run = tmp_path / "runs" / "tiny" / "version_0"
    main(["test", "--config", config, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    assert f"its priors alone (untrained) rows for the report, into {run / 'priors_alone'}" in (
        capsys.readouterr().out
    )
    summary = json.loads((run / "voe_report" / "summary.json").read_text())
    priors = summary["priors_alone"]
    assert (priors["label"], priors["seed"]) == ("priors alone (untrained)", 0)
    assert Path(priors["report"], "summary.json").is_file()
    cases = [(row["concept"], row["variant"]) for row in summary["rows"]]
    assert [(row["concept"], row["variant"]) for row in priors["rows"]] == cases
    assert [v["concept"] for v in priors["verdicts"]] == ["object_persistence"]
    main(["analyze", "null", "--configs", f"[{config}]", "--seeds", "1", "--out", "untrained"])
    [initialization] = json.loads((tmp_path / "untrained" / "null.json").read_text())[
        "initializations"
    ]
    assert [row["t"] for row in priors["rows"]] == [row["t"] for row in initialization["rows"]]
    assert [row["t"] for row in priors["rows"]] != [row["t"] for row in summary["rows"]]
    markdown = (run / "voe_report" / "summary.md").read_text()
    assert "## Priors alone (untrained)" in markdown
    assert "| concept | variant | t trained | t priors alone (untrained) |" in markdown
    trained, alone = summary["verdicts"][0]["verdict"], priors["verdicts"][0]["verdict"]
    assert f"- object_persistence: trained {trained}; priors alone (untrained) {alone}" in markdown
