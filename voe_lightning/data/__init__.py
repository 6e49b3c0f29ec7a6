"""The generated data: the store that holds it (``store``: planned, rendered and written as
shards with a manifest, and read as Datasets), the ``generate`` command that fills one
(``generate``, with ``video_presets``) and the contact sheets that show it (``contact_sheet``)."""
