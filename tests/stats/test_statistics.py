"""The VOE statistics against scipy: one-shot paired test, the stratified pooled test (one-shot
and streaming) against a hand computation, degenerate inputs, the streaming metric's exactness
when states from several processes are merged (simulated DDP), the verdict rules and the one
alpha."""

import ast
import json
import math

import numpy as np
import pytest
import torch
import yaml
from helpers import ALPHA
from helpers.locations import REPO
from scipy import stats
from sklearn.metrics import roc_auc_score

from voe_lightning import specs
from voe_lightning.stats import statistics, statistics_format, t_tests, verdicts
from voe_lightning.stats.statistics import PairedTestResult, effect_size_interval, paired_test
from voe_lightning.stats.streaming_statistics import PairedSurpriseStats, pooled_values


def _surprise(n, effect, seed):
    rng = np.random.default_rng(seed)
    consistent = rng.gamma(2.0, 5.0, size=n)
    return consistent + rng.normal(effect, 2.0, size=n), consistent


@pytest.mark.parametrize(
    "n, effect, seed", [(2, 0.5, 0), (7, -0.4, 1), (50, 0.3, 2), (3000, 0.1, 3)]
)
def test_paired_test_agrees_with_scipy(n, effect, seed):
    inconsistent, consistent = _surprise(n, effect, seed)
    result = paired_test(inconsistent, consistent, bootstrap=200, alpha=ALPHA)
    reference = stats.ttest_rel(inconsistent, consistent, alternative="greater")
    d = inconsistent - consistent
    assert result.n == n and result.df == n - 1
    assert result.t == pytest.approx(reference.statistic, rel=1e-9, abs=1e-12)
    assert result.p_value == pytest.approx(reference.pvalue, rel=1e-9, abs=1e-300)
    assert result.relative_surprise == pytest.approx(d.mean(), rel=1e-12)
    assert result.sd == pytest.approx(d.std(ddof=1), rel=1e-12)
    assert result.d_z == pytest.approx(d.mean() / d.std(ddof=1), rel=1e-12)
    assert result.significant == (reference.pvalue < ALPHA)
    assert result.accuracy == np.mean(d > 0)
    labels = np.r_[np.ones(n), np.zeros(n)]
    reference_auroc = roc_auc_score(labels, np.r_[inconsistent, consistent])
    assert result.auroc == pytest.approx(reference_auroc, abs=1e-6)
    assert result.note == ""


def test_tensors_and_lists_are_accepted_and_dict_is_flat():
    inconsistent, consistent = _surprise(20, 0.5, 4)
    from_numpy = paired_test(inconsistent, consistent, bootstrap=100, alpha=ALPHA)
    from_torch = paired_test(
        torch.tensor(inconsistent, dtype=torch.float64),
        torch.tensor(consistent, dtype=torch.float64),
        bootstrap=100,
        alpha=ALPHA,
    )
    from_list = paired_test(list(inconsistent), list(consistent), bootstrap=100, alpha=ALPHA)
    assert from_numpy == from_torch == from_list
    row = from_numpy.as_dict()
    assert list(row) == [f.name for f in PairedTestResult.__dataclass_fields__.values()]
    with pytest.raises(AttributeError):
        from_numpy.t = 0.0  # frozen


def test_effect_size_interval_is_the_noncentral_t_interval():
    inconsistent, consistent = _surprise(40, 0.8, 5)
    result = paired_test(inconsistent, consistent, bootstrap=0, alpha=ALPHA)
    n, root_n = result.n, math.sqrt(result.n)
    # At the bounds the observed t is the 97.5% / 2.5% quantile of the noncentral t.
    low_tail = stats.nct.cdf(result.t, n - 1, result.d_z_ci_low * root_n)
    high_tail = stats.nct.cdf(result.t, n - 1, result.d_z_ci_high * root_n)
    assert low_tail == pytest.approx(0.975, abs=1e-8)
    assert high_tail == pytest.approx(0.025, abs=1e-8)
    assert result.d_z_ci_low < result.d_z < result.d_z_ci_high
    # Large t with few degrees of freedom still brackets; the paper-scale case stays finite.
    low, high = effect_size_interval(300.0, 11)
    assert low < 300 / math.sqrt(11) < high
    low, high = effect_size_interval(136.25, 8000)
    assert low < 136.25 / math.sqrt(8000) < high


def test_bootstrap_interval_is_seeded_and_covers_the_mean():
    inconsistent, consistent = _surprise(200, 0.4, 6)
    first = paired_test(inconsistent, consistent, bootstrap=500, seed=1, alpha=ALPHA)
    again = paired_test(inconsistent, consistent, bootstrap=500, seed=1, alpha=ALPHA)
    other = paired_test(inconsistent, consistent, bootstrap=500, seed=2, alpha=ALPHA)
    assert first == again
    assert first.relative_surprise_ci_low != other.relative_surprise_ci_low
    low, high = first.relative_surprise_ci_low, first.relative_surprise_ci_high
    assert low < first.relative_surprise < high
    # Its width matches the t-interval of the mean to within bootstrap noise.
    half_t = stats.t.ppf(0.975, 199) * first.sd / math.sqrt(200)
    width = first.relative_surprise_ci_high - first.relative_surprise_ci_low
    assert width == pytest.approx(2 * half_t, rel=0.2)


def test_no_bootstrap_gives_nan_bounds_with_a_note():
    result = paired_test([1.0, 2.5, 3.0], [0.5, 2.0, 3.5], bootstrap=0, alpha=ALPHA)
    assert math.isnan(result.relative_surprise_ci_low) and "bootstrap=0" in result.note


def test_fewer_than_two_pairs_is_refused():
    with pytest.raises(ValueError, match="at least 2 probe pairs, got n=1"):
        paired_test([1.0], [0.0], alpha=ALPHA)
    with pytest.raises(ValueError, match="n=0"):
        paired_test([], [], alpha=ALPHA)


def test_nan_surprise_is_refused_naming_how_many():
    inconsistent = np.array([1.0, np.nan, 2.0, np.nan, np.inf])
    with pytest.raises(ValueError, match=r"3 non-finite value\(s\) out of 5 \(2 NaN, 1 infinite\)"):
        paired_test(inconsistent, np.zeros(5), alpha=ALPHA)
    with pytest.raises(ValueError, match="consistent surprise has 1 non-finite"):
        paired_test(np.zeros(3), [0.0, np.nan, 1.0], alpha=ALPHA)


def test_mismatched_or_per_frame_input_is_refused():
    with pytest.raises(ValueError, match="3 inconsistent and 2 consistent"):
        paired_test([1.0, 2.0, 3.0], [1.0, 2.0], alpha=ALPHA)
    with pytest.raises(ValueError, match=r"shape \[n\]; got shape \(2, 15\)"):
        paired_test(np.zeros((2, 15)), np.zeros((2, 15)), alpha=ALPHA)
    with pytest.raises(ValueError, match="alpha"):
        paired_test([1.0, 2.0], [0.0, 0.0], alpha=5)


def test_zero_variance_positive_difference():
    consistent = np.array([1.0, 4.0, 2.5, 7.0])
    result = paired_test(consistent + 0.1, consistent, bootstrap=100, alpha=ALPHA)
    assert result.t == math.inf and result.p_value == 0.0 and result.significant
    assert result.d_z == math.inf and result.d_z_ci_low == math.inf
    assert result.relative_surprise == pytest.approx(0.1)
    assert result.relative_surprise_ci_low == result.relative_surprise_ci_high == pytest.approx(0.1)
    assert "t = +inf, p = 0" in result.note


def test_zero_variance_negative_difference():
    result = paired_test([0.0, 1.0, 2.0], [0.5, 1.5, 2.5], bootstrap=100, alpha=ALPHA)
    assert result.t == -math.inf and result.p_value == 1.0 and not result.significant
    assert result.accuracy == 0.0 and "t = -inf, p = 1" in result.note


def test_identical_surprise_is_not_significant_and_says_why():
    surprise = [3.0, 1.0, 2.0]
    result = paired_test(surprise, surprise, bootstrap=100, alpha=ALPHA)
    assert math.isnan(result.t) and math.isnan(result.d_z)
    assert result.p_value == 1.0 and not result.significant
    assert result.relative_surprise == 0.0 and result.accuracy == 0.0 and result.auroc == 0.5
    assert "every d = 0" in result.note


def _stream(inconsistent, consistent, batch):
    metric = PairedSurpriseStats()
    for start in range(0, len(inconsistent), batch):
        metric.update(
            torch.tensor(inconsistent[start : start + batch]),
            torch.tensor(consistent[start : start + batch]),
        )
    return metric


def _assert_matches_scipy(values, inconsistent, consistent):
    reference = stats.ttest_rel(inconsistent, consistent, alternative="greater")
    d = inconsistent - consistent
    assert values["n"].item() == len(d)
    assert values["relative_surprise"].item() == pytest.approx(d.mean(), rel=1e-12)
    assert values["t"].item() == pytest.approx(reference.statistic, rel=1e-9)
    assert values["p_value"].item() == pytest.approx(reference.pvalue, rel=1e-9)
    assert values["accuracy"].item() == np.mean(d > 0)


def test_streaming_metric_agrees_with_scipy_and_one_shot():
    inconsistent, consistent = _surprise(333, 0.2, 7)
    values = _stream(inconsistent, consistent, batch=10).compute()
    assert all(value.dtype == torch.float64 for value in values.values())
    _assert_matches_scipy(values, inconsistent, consistent)
    one_shot = paired_test(inconsistent, consistent, bootstrap=0, alpha=ALPHA)
    assert values["t"].item() == pytest.approx(one_shot.t, rel=1e-9)
    assert values["p_value"].item() == pytest.approx(one_shot.p_value, rel=1e-9)


@pytest.mark.filterwarnings("ignore:The ``compute`` method")  # merged states, no own update
def test_streaming_states_merge_exactly_like_ddp():
    inconsistent, consistent = _surprise(250, 0.3, 8)
    whole = _stream(inconsistent, consistent, batch=250)
    # Three "ranks" with uneven shards; float32 input is upcast to the float64 states.
    shards = [slice(0, 90), slice(90, 91), slice(91, 250)]
    ranks = [_stream(inconsistent[s], consistent[s], batch=17) for s in shards]
    merged = PairedSurpriseStats()
    for rank in ranks:
        merged.merge_state(rank)
    summed = PairedSurpriseStats()
    summed.merge_state(
        {
            name: sum(getattr(r, name) for r in ranks)
            for name in ("n", "sum_d", "sum_d_squared", "positive")
        }
    )
    for metric in (merged, summed):
        assert metric.n.item() == whole.n.item() == 250
        assert metric.positive.item() == whole.positive.item()
        assert metric.sum_d.item() == pytest.approx(whole.sum_d.item(), rel=1e-14)
        values = metric.compute()
        _assert_matches_scipy(values, inconsistent, consistent)
    assert all(
        state.dtype == torch.float64
        for state in (merged.n, merged.sum_d, merged.sum_d_squared, merged.positive)
    )


def test_streaming_states_survive_dtype_casts_and_reset():
    metric = PairedSurpriseStats().half()  # Lightning's precision casts must not touch states
    metric.update(torch.tensor([1.0, 2.0, 4.0]), torch.tensor([0.5, 2.5, 1.0]))
    assert metric.sum_d.dtype == torch.float64
    metric.reset()
    assert metric.n.item() == 0.0


def test_streaming_degenerate_inputs():
    metric = PairedSurpriseStats()
    metric.update(torch.tensor([1.0]), torch.tensor([0.0]))
    with pytest.raises(ValueError, match="at least 2 probe pairs, got n=1"):
        metric.compute()
    with pytest.raises(ValueError, match="2 of 3 probe pairs in this batch have non-finite"):
        metric.update(torch.tensor([1.0, float("nan"), float("inf")]), torch.zeros(3))
    with pytest.raises(ValueError, match=r"shape \[B\]"):
        metric.update(torch.zeros(2, 15), torch.zeros(2, 15))
    equal = PairedSurpriseStats()
    equal.update(
        torch.tensor([1.1, 2.1, 3.1], dtype=torch.float64),
        torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64),
    )
    values = equal.compute()  # d = 0.1 up to rounding: exactly the zero-variance rule
    assert values["t"].item() == math.inf and values["p_value"].item() == 0.0


# ----------------------------------------------------------------------------- verdicts


def _result(p, mean):
    return {"p_value": p, "relative_surprise": mean}


def test_pooled_verdict_needs_the_pool_and_both_variants_significant():
    from voe_lightning.stats.verdicts import concept_verdicts

    def verdict(standard, counterbalanced, pooled, alpha=0.01):
        results = {
            ("continuity", "standard"): standard,
            ("continuity", "counterbalanced"): counterbalanced,
            ("continuity", "pooled"): pooled,
        }
        return concept_verdicts(results, alpha)[0]

    assert verdict(_result(0.001, 2.0), _result(0.005, 0.1), _result(0.001, 1.0)).voe is True
    failed = verdict(_result(0.001, 5.0), _result(0.9, -0.5), _result(0.001, 2.0))
    assert failed.voe is False and failed.text() == "no VOE: counterbalanced M = -0.5 <= 0"
    # M > 0 is not enough: a cue pointing the wrong way plus noise gets there (calibration).
    positive = verdict(_result(0.001, 5.0), _result(0.3, 0.2), _result(0.001, 2.0))
    assert positive.text() == "no VOE: counterbalanced p = .300 >= 0.01"
    weak = verdict(_result(0.005, 1.0), _result(0.005, 0.5), _result(0.02, 0.7))
    assert weak.text() == "no VOE: pooled p = .020 >= 0.01"
    assert "stratified pooled test and in both standard and counterbalanced" in weak.rule
    assert "p < 0.01" in weak.rule
    assert verdict(_result(0.005, 1.0), _result(0.005, 0.5), _result(0.02, 0.7), alpha=0.05).voe
    assert (
        concept_verdicts({("continuity", "pooled"): _result(0.02, 0.7)}, alpha=ALPHA)[0].voe is None
    )
    missing = concept_verdicts({("continuity", "standard"): _result(0.001, 3.0)}, alpha=ALPHA)[0]
    assert missing.voe is None and "counterbalanced, pooled" in missing.text()


def test_unchangeableness_verdict_needs_each_change_quadruplet():
    """Each change is its own quadruplet: VOE only when all three quadruplet tests are
    significant with both halves above 0; the halves' own rows and the generalization
    variants are reported beside it. Without quadruplet rows (the training-time table pairs
    no seeds) every half must be significant."""
    from voe_lightning.stats.verdicts import concept_verdicts

    def quadruplet_row(p, first=1.0, second=0.5):
        return {
            "p_value": p,
            "relative_surprise": first + second,
            "first_half": first,
            "second_half": second,
        }

    results = {
        ("unchangeableness", f"{change}_quadruplet"): quadruplet_row(0.001)
        for change in specs.UNCHANGEABLENESS_CHANGES
    }
    results[("unchangeableness", "color_plus1")] = _result(0.9, -1.0)  # generalization: ignored
    results[("unchangeableness", "position")] = _result(0.9, -1.0)  # a half: beside the test
    assert concept_verdicts(results, alpha=ALPHA)[0].voe is True
    assert "of each change" in concept_verdicts(results, alpha=ALPHA)[0].rule
    results[("unchangeableness", "shape_quadruplet")] = quadruplet_row(0.02)
    assert (
        concept_verdicts(results, alpha=ALPHA)[0].text()
        == "no VOE: shape_quadruplet p = .020 >= 0.01"
    )
    assert concept_verdicts(results, alpha=0.05)[0].voe is True
    results[("unchangeableness", "color_quadruplet")] = quadruplet_row(0.001, 2.0, -0.5)
    assert concept_verdicts(results, alpha=0.05)[0].text() == (
        "no VOE: color_counterbalanced half M = -0.5 <= 0"
    )
    del results[("unchangeableness", "position_quadruplet")]
    missing = concept_verdicts(results, alpha=ALPHA)[0]
    assert missing.voe is None and "no test of position_quadruplet" in missing.text()

    halves = {
        ("unchangeableness", v): _result(0.005, 1.0)
        for v in specs.VERDICT_VARIANTS["unchangeableness"]
    }
    assert concept_verdicts(halves, alpha=ALPHA)[0].voe is True
    halves[("unchangeableness", "shape_counterbalanced")] = _result(0.02, 0.4)
    assert concept_verdicts(halves, alpha=ALPHA)[0].text() == (
        "no VOE: shape_counterbalanced p = .020 >= 0.01"
    )


def test_the_verdict_rule_takes_arrays_as_concept_verdicts_takes_rows():
    """The calibration applies the rule to thousands of repetitions at once: element by
    element it must decide as ``concept_verdicts`` does."""
    from voe_lightning.stats.verdicts import concept_verdicts, verdict_rule

    rng = np.random.default_rng(3)
    cases = {
        "solidity": ("standard", "counterbalanced", "pooled"),
        "unchangeableness": specs.VERDICT_VARIANTS["unchangeableness"],
    }
    for concept, variants in cases.items():
        p = rng.uniform(0, 0.02, (len(variants), 60))
        vectorized = verdict_rule(p, 0.01)
        assert 0 < vectorized.sum() < 60
        for i in range(60):
            rows = {(concept, v): _result(p[k, i], 1.0) for k, v in enumerate(variants)}
            assert concept_verdicts(rows, 0.01)[0].voe == vectorized[i]


# ----------------------------------------------------------------------------- stratified test


def _hand_stratified(d1, d2):
    """M, SE, Welch-Satterthwaite df and one-tailed p written out with numpy and scipy."""
    v1, v2 = d1.var(ddof=1) / d1.size, d2.var(ddof=1) / d2.size
    mean = (d1.mean() + d2.mean()) / 2
    standard_error = 0.5 * np.sqrt(v1 + v2)
    df = (v1 + v2) ** 2 / (v1**2 / (d1.size - 1) + v2**2 / (d2.size - 1))
    return mean, standard_error, df, stats.t.sf(mean / standard_error, df)


@pytest.mark.parametrize(
    "sizes, effects, seed",
    [((12, 9), (1.5, -1.0), 0), ((48, 48), (0.4, 0.2), 1), ((3, 200), (-0.3, 0.6), 2)],
)
def test_pooled_test_is_the_stratified_test_computed_by_hand(sizes, effects, seed):
    rng = np.random.default_rng(seed)
    # The variants' means differ by design (opposite cues) and so do their spreads.
    d = [rng.normal(effect, 1.0 + k, size) for k, (size, effect) in enumerate(zip(sizes, effects))]
    consistent = rng.gamma(2.0, 5.0, sum(sizes))
    inconsistent = consistent + np.concatenate(d)
    strata = ["standard"] * sizes[0] + ["counterbalanced"] * sizes[1]
    result = statistics.pooled_test(inconsistent, consistent, strata, bootstrap=300, alpha=ALPHA)
    mean, standard_error, df, p = _hand_stratified(*d)
    assert result.n == sum(sizes)
    assert result.relative_surprise == pytest.approx(mean, rel=1e-12)
    assert result.t == pytest.approx(mean / standard_error, rel=1e-12)
    assert result.df == pytest.approx(df, rel=1e-12)
    assert result.p_value == pytest.approx(p, rel=1e-9)
    # scipy's Welch test of d1 against -d2 is the same test: t = (M1 + M2) / sqrt(v1 + v2).
    welch = stats.ttest_ind(d[0], -d[1], equal_var=False, alternative="greater")
    assert result.t == pytest.approx(welch.statistic, rel=1e-12)
    assert result.p_value == pytest.approx(welch.pvalue, rel=1e-9)
    assert result.significant == (p < ALPHA)
    union = np.concatenate(d)
    assert result.sd == pytest.approx(union.std(ddof=1), rel=1e-12)
    assert result.d_z == pytest.approx(mean / union.std(ddof=1), rel=1e-12)
    half = stats.t.ppf(0.975, df) * standard_error / union.std(ddof=1)
    assert result.d_z_ci_low == pytest.approx(result.d_z - half, rel=1e-9)
    assert result.accuracy == np.mean(union > 0)
    assert result.relative_surprise_ci_low < mean < result.relative_surprise_ci_high


def test_stratified_test_has_more_power_than_the_union_when_variants_split():
    """Mirrored variants (means +2 and -1.6): the union counts their split as noise."""
    rng = np.random.default_rng(4)
    d1, d2 = rng.normal(2.0, 0.5, 40), rng.normal(-1.6, 0.5, 40)
    strata = ["standard"] * 40 + ["counterbalanced"] * 40
    pooled = statistics.pooled_test(np.r_[d1, d2], np.zeros(80), strata, bootstrap=0, alpha=ALPHA)
    union = stats.ttest_1samp(np.r_[d1, d2], 0.0, alternative="greater")
    assert pooled.p_value < 0.01 < 0.1 < union.pvalue


def test_streaming_pooled_values_equal_the_one_shot_pooled_test():
    rng = np.random.default_rng(5)
    sizes, effects = (30, 17), (0.8, -0.3)
    parts = []
    for size, effect in zip(sizes, effects):
        consistent = rng.gamma(2.0, 5.0, size)
        parts.append((consistent + rng.normal(effect, 2.0, size), consistent))
    streamed = [
        {k: v.item() for k, v in _stream(inc, con, batch=7).compute().items()} for inc, con in parts
    ]
    pooled = pooled_values(streamed)
    one_shot = statistics.pooled_test(
        np.r_[parts[0][0], parts[1][0]],
        np.r_[parts[0][1], parts[1][1]],
        ["standard"] * sizes[0] + ["counterbalanced"] * sizes[1],
        bootstrap=0,
        alpha=ALPHA,
    )
    assert pooled["n"] == one_shot.n == sum(sizes)
    for key in ("relative_surprise", "t", "df", "p_value", "accuracy"):
        assert pooled[key] == pytest.approx(getattr(one_shot, key), rel=1e-9), key


def test_stratified_degenerate_and_refused_inputs():
    # Every d equal within each variant: zero standard error, the one-variant rule decides.
    zero = t_tests.stratified_test([(4, 0.5, 0.0), (6, 0.1, 0.0)])
    assert zero.t == math.inf and zero.p_value == 0.0 and "t = +inf" in zero.note
    nothing = t_tests.stratified_test([(4, 0.0, 0.0), (6, 0.0, 0.0)])
    assert math.isnan(nothing.t) and nothing.p_value == 1.0
    # One variant without spread: the other's alone gives SE and df = n - 1.
    one = t_tests.stratified_test([(5, 1.0, 0.0), (8, 0.2, 0.5)])
    assert one.df == pytest.approx(7.0) and one.standard_error == pytest.approx(
        0.5 * math.sqrt(0.5 / 8)
    )
    with pytest.raises(ValueError, match="at least 2 strata"):
        t_tests.stratified_test([(5, 1.0, 1.0)])
    with pytest.raises(ValueError, match="at least 2 probe pairs, got n=1"):
        t_tests.stratified_test([(5, 1.0, 1.0), (1, 0.3, 0.0)])
    with pytest.raises(ValueError, match="counterbalanced has 1 pair"):
        statistics.pooled_test(
            [1.0, 2.0, 3.0],
            [0.0, 0.0, 0.0],
            ["standard", "standard", "counterbalanced"],
            alpha=ALPHA,
        )
    with pytest.raises(ValueError, match="at least 2 variants"):
        statistics.pooled_test([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], ["standard"] * 3, alpha=ALPHA)


# ----------------------------------------------------------------------------- alpha


def test_alpha_has_one_home_the_base_config_and_bad_values_are_named():
    """No module-level default decides a verdict: a function taking ``alpha`` requires it, or
    takes None for "the rows' own" or "the run's" (the CLI's and commands' default is
    configs/base.yaml's, ``base_alpha``)."""
    base = yaml.safe_load((REPO / "configs" / "base.yaml").read_text())
    assert base["alpha"] == ALPHA == 0.01
    assert not hasattr(statistics, "ALPHA")
    defaulted = []
    for path in (REPO / "voe_lightning").rglob("*.py"):
        if path.parent.name == "scenes":  # a colour's alpha, not a significance level
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                arguments = node.args
                positional = arguments.posonlyargs + arguments.args
                pairs = list(
                    zip(positional[len(positional) - len(arguments.defaults) :], arguments.defaults)
                )
                pairs += [
                    (a, d)
                    for a, d in zip(arguments.kwonlyargs, arguments.kw_defaults)
                    if d is not None
                ]
                defaulted += [
                    f"{path.name}:{node.name}"
                    for a, default in pairs
                    if a.arg == "alpha"
                    and not (isinstance(default, ast.Constant) and default.value is None)
                ]
    assert defaulted == []
    for bad in (0, 1, 1.5, -0.1, "0.05", True):
        with pytest.raises(ValueError, match=r"alpha must be a significance level in \(0, 1\)"):
            statistics.check_alpha(bad)
    assert statistics_format.format_alpha(0.01) == "α = 0.01"


def test_json_row_writes_non_finite_values_as_strings_float_reads_back():
    row = {
        "concept": "solidity",
        "t": float("inf"),
        "d_z": float("-inf"),
        "p": float("nan"),
        "n": 3,
        "M": 0.5,
    }
    encoded = json.loads(json.dumps(statistics_format.json_row(row), allow_nan=False))
    assert encoded == {
        "concept": "solidity",
        "t": "inf",
        "d_z": "-inf",
        "p": "nan",
        "n": 3,
        "M": 0.5,
    }
    assert float(encoded["t"]) == math.inf and math.isnan(float(encoded["p"]))


def test_one_row_formatter_writes_each_number_alike_in_every_style():
    """statistics_format.row_text is the one place a row's numbers become text: the report,
    figures, cue cells, the comparison and the console table only choose a precision."""
    d = np.array([1.0, 2.0, 0.5, -0.2, 1.5, 0.9])
    row = {
        "concept": "solidity",
        "variant": "pooled",
        **statistics.pooled_test(
            d + 1.0,
            np.ones(6),
            ["standard"] * 3 + ["counterbalanced"] * 3,
            bootstrap=0,
            alpha=ALPHA,
        ).as_dict(),
    }
    report = statistics_format.row_text(row)
    assert report.t.startswith(f"t({row['df']:.1f}) = ")  # a real-valued df, one decimal
    assert report.accuracy == f"{100 * row['accuracy']:.1f}%" and report.sig in ("yes *", "no")
    assert report.mean_interval == report.mean  # bootstrap=0: no interval of M
    brief = statistics_format.row_text(row, statistics_format.BRIEF)
    assert brief.accuracy == f"{100 * row['accuracy']:.0f}%" and brief.t == report.t
    console = statistics_format.row_text(
        {key: row[key] for key in ("n", "relative_surprise", "t", "p_value", "accuracy")},
        statistics_format.CONSOLE,
        alpha=0.5,
    )
    assert (console.n, console.mean, console.t, console.accuracy) == (
        "6",
        f"{row['relative_surprise']:.3f}",
        f"{row['t']:.2f}",
        f"{row['accuracy']:.2f}",
    )
    assert console.p == f"{row['p_value']:.3g}" and console.star == "*"
    # a row read back from summary.json, non-finite values as strings
    untested = statistics_format.row_text({"n": 1, "t": None, "p_value": None, "accuracy": None})
    assert (untested.t, untested.p, untested.sig, untested.accuracy) == ("n/a",) * 4
    degenerate = statistics_format.row_text(
        statistics_format.json_row(
            {
                "n": 3,
                "relative_surprise": 1.0,
                "t": math.inf,
                "df": 2,
                "p_value": 0.0,
                "d_z": math.inf,
                "relative_surprise_ci_low": math.nan,
                "relative_surprise_ci_high": math.nan,
                "significant": True,
            }
        )
    )
    assert (degenerate.t, degenerate.p, degenerate.d_z, degenerate.mean_interval) == (
        "t(2) = +inf",
        "< .001",
        "+inf",
        "1",
    )


def test_a_nan_p_is_undefined_and_a_p_beside_alpha_shows_the_digits_of_its_verdict():
    """format_p(NaN) was '1'; p = .0103 beside α = .01 was '.010 ... no' (issue 59)."""
    fmt = statistics_format
    assert fmt.format_p(math.nan) == fmt.format_p("nan") == "undefined"
    assert fmt.format_p_phrase(np.float32("nan"), 0.01) == "p = undefined"
    assert fmt.format_p(0.0103, 0.01) == ".0103" and fmt.format_p(0.0097, 0.01) == ".0097"
    assert fmt.format_p(0.0100001, 0.01) == ".0100001" and fmt.format_p(0.01, 0.01) == ".010"
    # anywhere else, three decimals or '< .001', as before
    assert [fmt.format_p(p, 0.01) for p in (0.034, 0.0004, 0.0123, 0.99, 1.0)] == [
        ".034",
        "< .001",
        ".012",
        ".990",
        "1",
    ]
    assert fmt.format_p(0.0103) == ".010"  # no alpha: no verdict beside it
    row = {"n": 9, "t": 3.0, "df": 8, "p_value": 0.0103, "alpha": 0.01, "significant": False}
    report = fmt.row_text(row)
    assert (report.p, report.p_phrase, report.sig) == (".0103", "p = .0103", "no")
    console = fmt.row_text({**row, "p_value": 0.009996}, fmt.CONSOLE)
    assert console.p == ".009996" and fmt.row_text(row, fmt.CONSOLE).p == "0.0103"
    verdict = verdicts.concept_verdicts(
        [
            {"concept": "mine", "variant": variant, "p_value": 0.0103, "relative_surprise": 1.0}
            for variant in ("a", "b")
        ],
        0.01,
    )
    assert "p = .0103 >= 0.01" in verdict[0].reason


# ----------------------------------------------------------------------------- quadruplet test


@pytest.mark.parametrize("n, effect, seed", [(2, 0.5, 0), (25, 0.3, 1), (200, -0.1, 2)])
def test_quadruplet_test_agrees_with_scipy_over_d(n, effect, seed):
    """D = [S(AB) - S(A)] + [S(BA) - S(B)] per quadruplet, one-tailed t over quadruplets as
    scipy's one-sample test of D, accuracy the share of D > 0, and the halves' means."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(10, 2, n), rng.normal(10, 2, n)
    ab, ba = b + effect + rng.normal(0, 1, n), a + effect + rng.normal(0, 1, n)
    result = statistics.quadruplet_test(ab, a, ba, b, bootstrap=0, alpha=ALPHA)
    d = (ab - a) + (ba - b)
    expected = stats.ttest_1samp(d, 0.0, alternative="greater")
    assert result.n == n and result.df == n - 1
    assert result.t == pytest.approx(expected.statistic, rel=1e-10)
    assert result.p_value == pytest.approx(expected.pvalue, rel=1e-10)
    assert result.relative_surprise == pytest.approx(d.mean(), rel=1e-12)
    assert result.accuracy == np.mean(d > 0)
    assert result.first_half == pytest.approx(np.mean(ab - a), rel=1e-12)
    assert result.second_half == pytest.approx(np.mean(ba - b), rel=1e-12)
    with pytest.raises(
        ValueError, match=f"one pair per quadruplet alike; got {n} first and {n - 1} second"
    ):
        statistics.quadruplet_test(ab, a, ba[1:], b[1:], alpha=ALPHA)


def test_quadruplets_match_by_seed_and_the_report_tests_them():
    """The two halves of a quadruplet concept are matched by seed whatever their order; a
    seed without its other half is left out (a concept without a common seed gets no
    quadruplet group); a seed twice in one variant is refused."""
    from voe_lightning.report.pairs import PairResults
    from voe_lightning.report.tables import summarize
    from voe_lightning.stats.verdicts import concept_verdicts, pair_groups, quadruplets

    concepts = ["object_persistence"] * 7 + ["continuity"] * 2
    variants = [
        "standard",
        "counterbalanced",
        "counterbalanced",
        "standard",
        "standard",
        "counterbalanced",
        "counterbalanced",
        "standard",
        "counterbalanced",
    ]
    seeds = [5, 7, 5, 7, 9, 3, 11, 5, 6]  # continuity's two pairs: no common seed
    ((concept, row, first, second),) = quadruplets(concepts, variants, seeds)
    assert (concept, row) == ("object_persistence", "quadruplet")
    assert first.tolist() == [0, 3] and second.tolist() == [2, 1]  # seeds 5, 7
    groups = pair_groups(concepts, variants, seeds=seeds)
    assert [(c, v) for c, v, _ in groups] == [
        ("object_persistence", "standard"),
        ("object_persistence", "counterbalanced"),
        ("object_persistence", "pooled"),
        ("object_persistence", "quadruplet"),
        ("continuity", "standard"),
        ("continuity", "counterbalanced"),
        ("continuity", "pooled"),
    ]
    assert groups[3][2].tolist() == [0, 3, 2, 1]
    with pytest.raises(ValueError, match="object_persistence/standard holds seed 5 more than"):
        quadruplets(concepts + ["object_persistence"], variants + ["standard"], seeds + [5])
    # unchangeableness: each change's halves are matched on their own, a row per change
    changes = ["color_counterbalanced", "position", "color", "position_counterbalanced", "shape"]
    matched = quadruplets(["unchangeableness"] * 5, changes, [4, 4, 4, 4, 4])
    assert [(row, a.tolist(), b.tolist()) for _, row, a, b in matched] == [
        ("position_quadruplet", [1], [3]),
        ("color_quadruplet", [2], [0]),
    ]
    assert [v for _, v, _ in pair_groups(["unchangeableness"] * 5, changes, seeds=[4] * 5)] == [
        "position",
        "position_counterbalanced",
        "color",
        "color_counterbalanced",
        "shape",
        "position_quadruplet",
        "color_quadruplet",
    ]

    rng = np.random.default_rng(0)
    frames = rng.uniform(0, 1, (len(seeds), 2, 4))
    results = PairResults(
        concept=concepts,
        variant=variants,
        seed=seeds,
        manipulation_frame=[1] * len(seeds),
        surprise_consistent=frames[:, 0],
        surprise_inconsistent=frames[:, 1] + 1.0,
    )
    rows = {
        (row["concept"], row["variant"]): row
        for row in summarize(results, bootstrap=0, alpha=ALPHA)
    }
    row = rows[("object_persistence", "quadruplet")]
    total_con, total_inc = frames[:, 0].sum(1), frames[:, 1].sum(1) + 4.0
    d = total_inc - total_con
    assert row["n"] == 2 and row["relative_surprise"] == pytest.approx(
        d[[0, 3]].sum() / 2 + d[[2, 1]].sum() / 2
    )
    assert row["first_half"] == pytest.approx(d[[0, 3]].mean())
    assert rows[("continuity", "pooled")]["first_half"] is None
    verdict = concept_verdicts(list(rows.values()), alpha=ALPHA)[0]
    assert "quadruplet test, both halves M > 0" in verdict.rule


def test_quadruplet_verdict_needs_the_test_and_both_halves():
    from voe_lightning.stats.verdicts import concept_verdicts, quadruplet_rule

    def verdict(p, first, second):
        row = {
            "p_value": p,
            "relative_surprise": first + second,
            "first_half": first,
            "second_half": second,
        }
        return concept_verdicts(
            {
                ("object_persistence", "standard"): _result(0.9, -1.0),
                ("object_persistence", "quadruplet"): row,
            },
            alpha=ALPHA,
        )[0]

    assert verdict(0.001, 1.0, 0.5).voe is True  # a weak variant row does not decide it
    assert verdict(0.001, 3.0, -0.5).text() == "no VOE: counterbalanced half M = -0.5 <= 0"
    assert verdict(0.02, 1.0, 0.5).text() == "no VOE: quadruplet p = .020 >= 0.01"
    assert verdict(None, 1.0, 1.0).voe is None
    rules = quadruplet_rule(
        np.array([0.001, 0.001, 0.5]), np.array([1.0, -1.0, 1.0]), np.array([1.0, 1.0, 1.0]), 0.01
    )
    assert rules.tolist() == [True, False, False]


def test_each_quadruplet_half_is_tested_on_its_own_beside_the_verdict():
    from voe_lightning.stats.verdicts import concept_verdicts

    def verdict(standard_p, counterbalanced_p):
        rows = {
            ("object_persistence", "standard"): {**_result(standard_p, 2.0), "t": 5.0, "df": 9},
            ("object_persistence", "counterbalanced"): {
                **_result(counterbalanced_p, 0.2),
                "t": 1.9,
                "df": 9,
            },
            ("object_persistence", "quadruplet"): {
                "p_value": 1e-6,
                "relative_surprise": 2.2,
                "first_half": 2.0,
                "second_half": 0.2,
            },
        }
        return concept_verdicts(rows, alpha=0.01)[0]

    weak = verdict(1e-5, 0.03)
    assert weak.voe is True and weak.halves_significant is False
    assert weak.halves == "standard t(9) = 5.00, p < .001; counterbalanced t(9) = 1.90, p = .030"
    assert verdict(1e-5, 0.005).halves_significant is True
    lone = concept_verdicts(
        {
            ("object_persistence", "quadruplet"): {
                "p_value": 1e-6,
                "relative_surprise": 1.0,
                "first_half": 0.5,
                "second_half": 0.5,
            }
        },
        alpha=ALPHA,
    )[0]
    assert lone.halves_significant is None and lone.halves == ""
