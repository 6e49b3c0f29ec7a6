"""The ``export`` command (``command``): a store's probe split written in the field's formats,
for other harnesses and papers, each with a manifest (``manifest``) of versions, seeds,
quadruplets and file checksums; the split read as groups of pairs (``probes``). WebDataset tar
shards are written here (``webdataset``, with ``read_webdataset``); IntPhys 2's layout (mp4s and
metadata.csv) and IntPhys' (PNG frames and status.json labels) in each benchmark's home, beside
the reader that reads them back (``voe_lightning.benchmarks.intphys2.export``,
``voe_lightning.benchmarks.intphys.export``). No Lightning in them."""
