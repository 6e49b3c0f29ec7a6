"""A store's probe split written in the field's formats, for other harnesses and papers: IntPhys
2's layout (``intphys2``: mp4s and metadata.csv), IntPhys' (``intphys``: PNG frames and
status.json labels) and WebDataset tar shards (``webdataset``, with ``read_webdataset``),
each with a manifest (``manifest``) of versions, seeds, quadruplets and file checksums; the
split read as groups of pairs (``probes``); the ``export`` command (``command``). No
Lightning in them; ``voe_lightning.external`` reads the IntPhys layouts back."""
