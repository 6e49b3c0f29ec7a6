"""IntPhys metrics against hand-computed values, the paired test against scipy, and the
answer.txt format."""

import numpy as np
import pytest
from helpers import ALPHA
from scipy import stats

from voe_lightning.benchmarks.metrics import (
    absolute_error_rate,
    auroc,
    grouped_metrics,
    plausibility_from_surprise,
    quadruplet_metrics,
    read_answer_file,
    relative_error_rate,
    score_answers,
    write_answer_file,
)


def test_relative_error_counts_only_strictly_more_surprising_possible_movies_and_ties_half_beside():
    """Issue 10 case 14: the challenge's score.py counts a quadruplet as an error only when its
    possible movies' summed plausibility is strictly lower than the impossible movies' (with
    surprise, higher = less plausible: strictly higher); a tie is no error. The tie-as-half
    value is reported beside it under its own name."""
    possible = [[1, 2], [5, 1], [2, 2], [0.5, 0.5]]
    impossible = [[3, 4], [2, 3], [1, 3], [0, 1]]
    # surprise sums: 3 < 7 right, 6 > 5 error, 4 = 4 tie, 1 = 1 tie
    assert relative_error_rate(possible, impossible) == 1 / 4
    assert relative_error_rate(possible, impossible, tie_weight=0.5) == 2 / 4
    with pytest.raises(ValueError, match="same number"):
        relative_error_rate([[1, 2]], [[1, 2], [3, 4]])
    pairs = quadruplet_metrics(
        [0, 0, 1, 1, 2, 2, 3, 3], np.ravel(possible), np.ravel(impossible), bootstrap=0, alpha=ALPHA
    )
    assert pairs["relative_error_rate"] == 1 / 4
    assert pairs["relative_error_rate_ties_half"] == 2 / 4


def test_official_answer_scores_count_ties_as_no_error_and_report_ties_half_beside():
    plausibility = {
        # O1/a: possible 0.9 + 0.8 > impossible 0.1 + 0.2: right
        **{"O1/a/1": 0.9, "O1/a/2": 0.8, "O1/a/3": 0.1, "O1/a/4": 0.2},
        # O1/b: possible 0.3 + 0.3 < impossible 0.4 + 0.4: an error
        **{"O1/b/1": 0.3, "O1/b/2": 0.3, "O1/b/3": 0.4, "O1/b/4": 0.4},
        # O1/c: possible 0.5 + 0.5 = impossible 0.25 + 0.75: a tie, no error
        **{"O1/c/1": 0.5, "O1/c/2": 0.5, "O1/c/3": 0.25, "O1/c/4": 0.75},
    }
    labels = {movie: movie.endswith(("/1", "/2")) for movie in plausibility}
    scores = score_answers(plausibility, labels)["O1"]["all"]
    assert scores["relative_error_rate"] == pytest.approx(1 / 3)
    assert scores["relative_error_rate_ties_half"] == pytest.approx(1.5 / 3)
    # a constant submission ties everywhere: perfect under the official rule, chance with ties half
    constant = score_answers({movie: 0.5 for movie in plausibility}, labels)["O1"]["all"]
    assert constant["relative_error_rate"] == 0.0
    assert constant["relative_error_rate_ties_half"] == 0.5


def test_auroc_and_absolute_error_rate_by_hand():
    surprise = [3, 4, 2, 3, 1, 2, 5, 1]
    is_possible = [False] * 4 + [True] * 4
    # impossible {3,4,2,3} above possible {1,2,5,1}: 3 + 3 + 2.5 + 3 = 11.5 of 16 pairs
    assert auroc(surprise, is_possible) == pytest.approx(11.5 / 16)
    assert absolute_error_rate(surprise, is_possible) == pytest.approx(4.5 / 16)
    with pytest.raises(ValueError, match="both possible and impossible"):
        auroc([1, 2], [True, True])


def test_quadruplet_metrics_group_pairs_and_agree_with_scipy_on_the_paired_test():
    rng = np.random.default_rng(0)
    quadruplet = np.repeat(np.arange(10), 2)
    possible = rng.normal(10, 2, 20)
    impossible = possible + rng.normal(1, 1, 20)
    result = quadruplet_metrics(quadruplet, possible, impossible, bootstrap=0, alpha=ALPHA)
    sums_p = possible.reshape(10, 2).sum(1)
    sums_i = impossible.reshape(10, 2).sum(1)
    assert result["n_quadruplets"] == 10 and result["n_pairs"] == 20
    assert result["relative_error_rate"] == pytest.approx(np.mean(sums_p > sums_i))
    movies = np.concatenate([possible, impossible])
    wins = (impossible[:, None] > possible[None, :]).sum() + 0.5 * (
        impossible[:, None] == possible[None, :]
    ).sum()
    assert result["auroc"] == pytest.approx(wins / 400)
    assert result["absolute_error_rate"] == pytest.approx(1 - wins / 400)
    assert movies.size == 40
    scipy_test = stats.ttest_rel(impossible, possible, alternative="greater")
    assert result["paired_test"]["t"] == pytest.approx(scipy_test.statistic)
    assert result["paired_test"]["p_value"] == pytest.approx(scipy_test.pvalue)
    assert result["paired_test"]["df"] == 19


def test_grouped_metrics_split_by_group_and_subgroup():
    groups = ["O1"] * 4 + ["O2"] * 2
    quadruplet = [0, 0, 1, 1, 2, 2]
    subgroups = ["visible", "visible", "occluded", "occluded", None, None]
    possible = [1, 2, 5, 1, 2, 2]
    impossible = [3, 4, 2, 3, 1, 3]
    result = grouped_metrics(
        groups, quadruplet, possible, impossible, subgroups, bootstrap=0, alpha=ALPHA
    )
    assert set(result) == {"O1", "O2"}
    assert set(result["O1"]) == {"all", "visible", "occluded"} and set(result["O2"]) == {"all"}
    assert result["O1"]["all"]["relative_error_rate"] == 0.5
    assert result["O1"]["visible"]["relative_error_rate"] == 0.0
    assert result["O1"]["occluded"]["relative_error_rate"] == 1.0
    # O2's quadruplet ties (2 + 2 = 1 + 3): no error, half of one with ties half
    assert result["O2"]["all"]["relative_error_rate"] == 0.0
    assert result["O2"]["all"]["relative_error_rate_ties_half"] == 0.5
    assert result["O2"]["all"]["paired_test"]["n"] == 2


def test_plausibility_is_a_decreasing_affine_map_into_the_unit_interval():
    assert plausibility_from_surprise([2.0, 4.0, 3.0]).tolist() == [1.0, 0.0, 0.5]
    assert plausibility_from_surprise([7.0, 7.0]).tolist() == [0.5, 0.5]
    with pytest.raises(ValueError, match="finite"):
        plausibility_from_surprise([1.0, np.inf])


def test_answer_file_round_trip_and_official_scoring(tmp_path):
    surprise = {
        "O1/0001/1": 1.0,
        "O1/0001/2": 3.0,
        "O1/0001/3": 2.0,
        "O1/0001/4": 5.0,
        "O1/0002/1": 4.0,
        "O1/0002/2": 1.0,
        "O1/0002/3": 2.0,
        "O1/0002/4": 2.0,
    }
    path = write_answer_file(tmp_path / "answer.txt", surprise)
    assert path.read_text().splitlines() == [
        "O1/0001/1 1.0",  # exact (repr): rounding could turn a tie of sums into an error
        "O1/0001/2 0.5",
        "O1/0001/3 0.75",
        "O1/0001/4 0.0",
        "O1/0002/1 0.25",
        "O1/0002/2 1.0",
        "O1/0002/3 0.75",
        "O1/0002/4 0.75",
    ]
    answers = read_answer_file(path)
    labels = {
        "O1/0001/1": True,
        "O1/0001/3": True,
        "O1/0001/2": False,
        "O1/0001/4": False,
        "O1/0002/2": True,
        "O1/0002/3": True,
        "O1/0002/1": False,
        "O1/0002/4": False,
    }
    scores = score_answers(answers, labels)["O1"]["all"]
    # scene 1: possible 1.75 vs impossible 0.5 right; scene 2: 1.75 vs 1.0 right
    assert scores["relative_error_rate"] == 0.0
    # possible plausibilities {1, .75, 1, .75} vs impossible {.5, 0, .25, .75}: each 1 beats
    # all 4, each .75 beats 3 and ties 1: 15 of 16 pairs ranked right
    assert scores["absolute_error_rate"] == pytest.approx(1 / 16)


@pytest.mark.parametrize(
    "content, message",
    [
        ("O1/0001/1 0.5 extra\n", r"line 1: expected '<movie path> <plausibility>'"),
        ("O4/0001/1 0.5\n", r"movie path 'O4/0001/1' is not <block>/<scene>/<movie>"),
        ("O1/0001/5 0.5\n", r"movie path 'O1/0001/5'"),
        ("O1/0001/1 1.5\n", r"plausibility 1.5 is outside \[0, 1\]"),
        ("O1/0001/1 high\n", r"plausibility 'high' is not a number"),
        (
            "O1/0001/1 0.1\nO1/0001/2 0.1\nO1/0001/3 0.1\n",
            r"scene O1/0001 has movies \['1', '2', '3'\]",
        ),
    ],
)
def test_malformed_answer_files_are_refused_with_the_line(tmp_path, content, message):
    path = tmp_path / "answer.txt"
    path.write_text(content)
    with pytest.raises(ValueError, match=message):
        read_answer_file(path)


def test_writing_an_incomplete_scene_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"scene O2/0009 has movies \['1'\]"):
        write_answer_file(tmp_path / "answer.txt", {"O2/0009/1": 1.0})
