"""How a statistics row is written (docs/architecture.md §8): the one place that turns a row's
numbers (n, M with its interval, t with its df, p, significance, d_z, accuracy, AUROC) into
text, so that the training-time table, the report's summary, the cue audit, the comparison of
runs and the figures write the same number the same way.

A row is a mapping with the fields of ``statistics.PairedTestResult`` (a report row, a cue
row, a comparison row) or the subset the streaming form logs (n, relative_surprise, t,
p_value, accuracy, and a pooled row's df); ``None`` means "no test" and is written ``n/a``.
Tables differ only in how much precision they print, a ``RowStyle``: ``REPORT`` (summary.md),
``BRIEF`` (figures, the comparison, cue cells) and ``CONSOLE`` (the table ``fit`` prints).
Also here: the significance level as every table header prints it, and a row as strict JSON.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

__all__ = [
    "BRIEF",
    "CONSOLE",
    "REPORT",
    "RowStyle",
    "RowText",
    "format_alpha",
    "format_interval",
    "format_number",
    "format_p",
    "format_p_phrase",
    "format_t",
    "json_row",
    "row_text",
    "rows_alpha",
]


def format_alpha(alpha: float) -> str:
    """A significance level as every table header prints it: 'α = 0.01'."""
    return f"α = {alpha:g}"


def rows_alpha(rows: Iterable[Mapping[str, Any]]) -> float:
    """The significance level result rows were tested at (their ``alpha``); a ValueError
    when no row carries one."""
    alpha = next((row["alpha"] for row in rows if row.get("alpha") is not None), None)
    if alpha is None:
        raise ValueError("no row carries the alpha it was tested at")
    return float(alpha)


#: Non-finite floats as ``json_row`` writes them.
_NON_FINITE = ("nan", "inf", "-inf")


def format_number(value: Any, spec: str = ".3g") -> str:
    """A number for a table cell: 'n/a' for None, 'undefined' for NaN, '+inf' / '-inf' (also
    as ``json_row`` writes them, 'nan', 'inf' and '-inf', in rows read back from JSON)."""
    if value is None:
        return "n/a"
    if value in _NON_FINITE:
        value = float(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "undefined"
        if math.isinf(value):
            return "+inf" if value > 0 else "-inf"
    return format(value, spec)


def format_p(p: Any, alpha: float | None = None) -> str:
    """APA-style p value for a table cell: '< .001', '.034', '1'; 'undefined' for NaN (as
    ``format_number``). Beside a significance level ``alpha``, a p that three decimals would
    round onto or across it gets as many more digits as tell the two apart (p = .0103 beside
    α = .01 is '.0103', not '.010'), so the verdict can be read off the number."""
    if p is None:
        return "n/a"
    if p in _NON_FINITE:
        p = float(p)
    if p != p:  # NaN, of any float type
        return "undefined"
    if p < 0.001 and (alpha is None or alpha >= 0.001):
        return "< .001"
    if p >= 1:
        return "1"
    digits = 3
    text = f"{p:.{digits}f}"
    while alpha is not None and digits < 20:
        rounded = float(text)
        if (
            (rounded < alpha) == (p < alpha)
            and (rounded != alpha or p == alpha)
            and (rounded > 0 or p == 0)
        ):
            break
        digits += 1
        text = f"{p:.{digits}f}"
    return text.lstrip("0")


def format_p_phrase(p: Any, alpha: float | None = None) -> str:
    """'p < .001' or 'p = .034', as in the paper's text (``format_p``'s digits beside
    ``alpha``)."""
    text = format_p(p, alpha)
    return f"p {text}" if text.startswith("<") else f"p = {text}"


def format_t(t: float | None, df: float | str | None, spec: str = ".2f") -> str:
    """'t(47) = 2.31' as in the paper's text; a pooled row's real-valued Welch-Satterthwaite
    df with one decimal, 't(93.4) = 2.31'; 'n/a' without a test."""
    if t is None:
        return "n/a"
    df = float(df) if df in _NON_FINITE else df
    whole = (
        df is None or (isinstance(df, float) and not math.isfinite(df)) or float(df).is_integer()
    )
    degrees = format_number(df, ".0f") if whole else f"{df:.1f}"
    return f"t({degrees}) = {format_number(t, spec)}"


def format_interval(value: Any, low: Any, high: Any, spec: str) -> str:
    """'value [low, high]'; the value alone when the interval is missing (None, or NaN beside
    a number: not computed) or has no width."""
    if value is None:
        return "n/a"
    value, low, high = (float(x) if x in _NON_FINITE else x for x in (value, low, high))
    if low is None or (isinstance(low, float) and math.isnan(low) and not math.isnan(value)):
        return format_number(value, spec)
    if low == high == value:
        return format_number(value, spec)
    return f"{format_number(value, spec)} [{format_number(low, spec)}, {format_number(high, spec)}]"


@dataclass(frozen=True)
class RowStyle:
    """How precisely one kind of table writes a row's numbers (format specs): ``p`` None
    writes p APA-style (``format_p``), ``t_with_df`` writes 't(df) = t' rather than t alone;
    ``accuracy`` is a percent spec ('.1%': 61.3%) or a plain one ('.2f': 0.61)."""

    n: str = ""
    mean: str = ".3g"
    t: str = ".2f"
    t_with_df: bool = True
    p: str | None = None
    d_z: str = ".2f"
    accuracy: str = ".1%"
    auroc: str = ".3f"


#: summary.md: M [CI] to 3 significant digits, t(df), APA p, d_z [CI], accuracy to 0.1%.
REPORT = RowStyle()
#: Figures, the comparison of runs and cue cells: accuracy to whole percents.
BRIEF = replace(REPORT, accuracy=".0%")
#: The table ``fit`` prints at its end (``callbacks.voe_table``): fixed decimals, t alone.
CONSOLE = RowStyle(n=".0f", mean=".3f", t_with_df=False, p=".3g", accuracy=".2f")


@dataclass(frozen=True)
class RowText:
    """A row's cells as text (``row_text``); ``n/a`` where the row has no test; ``halves`` the
    quadruplet row's two halves' M, 'first / second' ('' for any other row)."""

    n: str
    mean: str
    mean_interval: str
    t: str
    p: str
    p_phrase: str
    significant: bool
    sig: str
    d_z: str
    d_z_interval: str
    accuracy: str
    auroc: str
    halves: str = ""

    @property
    def star(self) -> str:
        """'*' when the row is significant (the paper's mark), else ''."""
        return "*" if self.significant else ""


def row_text(
    row: Mapping[str, Any], style: RowStyle = REPORT, alpha: float | None = None
) -> RowText:
    """The cells of one statistics row in ``style``. A row is significant by its own
    ``significant`` field, or, lacking one (the streaming form), when p < ``alpha``
    (None: the row's ``alpha``)."""
    get = row.get
    tested = get("t") is not None
    level = alpha if alpha is not None else get("alpha")
    p = get("p_value")
    if get("significant") is not None:
        significant = bool(get("significant"))
    else:
        if tested and level is None:
            raise ValueError(
                f"the row {get('concept')}/{get('variant')} has no alpha to test its p at"
            )
        significant = tested and p is not None and level is not None and p < level
    accuracy = get("accuracy")
    return RowText(
        n=format_number(get("n"), style.n),
        mean=format_number(get("relative_surprise"), style.mean),
        mean_interval=format_interval(
            get("relative_surprise"),
            get("relative_surprise_ci_low"),
            get("relative_surprise_ci_high"),
            style.mean,
        ),
        t=(
            format_t(get("t"), get("df"), style.t)
            if style.t_with_df
            else format_number(get("t"), style.t)
        ),
        p=_p_text(p, style, level),
        p_phrase="n/a" if p is None else format_p_phrase(p, level),
        significant=significant,
        sig="n/a" if not tested else ("yes *" if significant else "no"),
        d_z=format_number(get("d_z"), style.d_z),
        d_z_interval=format_interval(get("d_z"), get("d_z_ci_low"), get("d_z_ci_high"), style.d_z),
        accuracy=format_number(accuracy, style.accuracy),
        auroc=format_number(get("auroc"), style.auroc),
        halves=(
            ""
            if get("first_half") is None
            else f"{format_number(get('first_half'), style.mean)} / "
            f"{format_number(get('second_half'), style.mean)}"
        ),
    )


def _p_text(p: Any, style: RowStyle, alpha: Any) -> str:
    """p in ``style``: APA-style (``format_p``), or its format spec unless that rounds p onto
    or across ``alpha``, where ``format_p``'s digits tell the two apart."""
    level = None if alpha is None or alpha in _NON_FINITE else float(alpha)
    if style.p is None:
        return format_p(p, level)
    text = format_number(p, style.p)
    if level is None or p in _NON_FINITE or p != p:
        return text
    rounded = float(text)
    if (rounded < level) == (p < level) and (rounded != level or p == level):
        return text
    return format_p(p, level)


def json_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """A statistics row as strict JSON: non-finite floats become the strings 'inf', '-inf' and
    'nan' (``float()`` reads them back; the row's note says why they are not finite)."""

    def value(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return _NON_FINITE[0] if math.isnan(v) else _NON_FINITE[1 if v > 0 else 2]
        return v

    return {key: value(v) for key, v in row.items()}
