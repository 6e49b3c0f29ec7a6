"""The statistics of a VOE probe: the paired tests (``statistics``) on the t-tests from moments
(``t_tests``) and their streaming form over batches (``streaming_statistics``), how they are printed (``statistics_format``), the verdicts
drawn from them (``verdicts``), the surprise window a video is scored over (``surprise_window``)
and the per-frame field metrics (``field_metrics``)."""
