"""The followers' rows of a report's cue audit (issue 70): tested like every cue, tabled on their
own, unchangeableness marked as the concept itself, a tie (every d = 0) said once, and the
concepts a follower passes by the verdict's own rule named."""

import numpy as np

from voe_lightning.audit.cue_report import followers_passing, format_followers, format_markdown
from voe_lightning.audit.cues import CueAudit
from voe_lightning.audit.followers import follower_cues


def test_follower_rows_are_tested_tabled_and_marked():
    rng = np.random.default_rng(0)
    n = 20
    concepts = np.array(["continuity"] * (2 * n) + ["unchangeableness"] * n, dtype=object)
    variants = np.array(["standard"] * n + ["counterbalanced"] * n + ["color"] * n, dtype=object)
    seeds = np.concatenate([np.arange(n), np.arange(n), np.arange(n)])
    cues = follower_cues("states")
    consistent = {cue: rng.normal(size=3 * n) for cue in cues}
    inconsistent = {cue: values.copy() for cue, values in consistent.items()}
    inconsistent["states_stay_put"] = consistent["states_stay_put"] + 1 + rng.normal(0, 0.1, 3 * n)
    audit = CueAudit(
        concepts, variants, {"consistent": consistent, "inconsistent": inconsistent}, seeds=seeds
    )
    assert audit.cue_names == cues
    rows = audit.rows(alpha=0.01)
    quadruplet = next(
        r for r in rows if r["cue"] == "states_stay_put" and r["variant"] == "quadruplet"
    )
    assert quadruplet["significant"] and quadruplet["n"] == n
    text = format_followers(rows)
    assert "| unchangeableness ‡ |" in text and "| continuity |" in text
    assert "states: stay put" in text and "every d = 0" in text
    assert "- continuity/standard, states: attributes: every d = 0" not in text  # said once
    assert "**Passed by a follower**" in text and "continuity (states: stay put)." in text
    assert followers_passing(rows) == {"continuity": ["states_stay_put"]}
    assert format_followers([r for r in rows if r["cue"] == "nothing"]) == ""


def test_cells_where_every_d_is_zero_are_one_line_under_any_cue_table():
    """A cue that scores both videos of every pair alike (every frame-local cue's quadruplet
    rows, by construction) is one sentence under the table, not a bullet per cell."""
    rng = np.random.default_rng(1)
    n = 12
    concepts = np.array(["solidity"] * (2 * n), dtype=object)
    variants = np.array(["standard"] * n + ["counterbalanced"] * n, dtype=object)
    seeds = np.concatenate([np.arange(n), np.arange(n)])
    cues = ["motion_energy", "pixel_novelty"]
    consistent = {cue: rng.normal(size=2 * n) for cue in cues}
    # the second half's inconsistent videos are the first half's consistent ones and back: a
    # scorer of frames after the change gives every quadruplet D = 0
    inconsistent = {cue: np.concatenate([v[n:], v[:n]]) for cue, v in consistent.items()}
    rows = CueAudit(
        concepts, variants, {"consistent": consistent, "inconsistent": inconsistent}, seeds=seeds
    ).rows(alpha=0.01)
    tied = [r for r in rows if "every d = 0" in (r.get("note") or "")]
    assert {r["variant"] for r in tied} == {"quadruplet"} and len(tied) == 2
    text = format_markdown(rows, cues=cues)
    assert text.count("every d = 0") == 1
    assert "- 2 cells score both videos of every pair alike" in text
    assert "scores every quadruplet 0 by construction" in text
