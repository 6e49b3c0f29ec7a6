"""The report's numbers under their former path (issue 49 split this module by idea), for
other people's code and notebooks: each name here is the very object of the module that now
holds it. The package itself imports those modules: ``pairs`` (``PairResults``, pairs.csv),
``tables`` (``summarize``, ``field_metric_rows``), ``markdown`` (summary.md's text),
``priors_alone`` (the untrained copy's rows), ``summary`` (``write_summary``) and
``summary_file`` (``read_summary``)."""

from voe_lightning.report.markdown import (
    VRNN_SURPRISE,
    format_markdown,
    format_source,
    format_verdicts,
)
from voe_lightning.report.pairs import FIRST_DIFFERENCE, PROBE_OUTPUT_KEYS, PairResults, as_numpy
from voe_lightning.report.priors_alone import (
    PRIORS_ALONE,
    PRIORS_ALONE_COLUMNS,
    format_priors_alone,
    priors_alone_document,
)
from voe_lightning.report.summary import write_summary
from voe_lightning.report.summary_file import read_summary
from voe_lightning.report.tables import SUMMARY_COLUMNS, field_metric_rows, summarize

__all__ = [
    "PROBE_OUTPUT_KEYS",
    "FIRST_DIFFERENCE",
    "SUMMARY_COLUMNS",
    "as_numpy",
    "PairResults",
    "read_summary",
    "summarize",
    "field_metric_rows",
    "format_verdicts",
    "VRNN_SURPRISE",
    "format_markdown",
    "PRIORS_ALONE",
    "PRIORS_ALONE_COLUMNS",
    "priors_alone_document",
    "format_priors_alone",
    "write_summary",
    "format_source",
]
