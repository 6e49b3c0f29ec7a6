"""The public benchmarks, one home each: ``intphys`` (IntPhys, Riochet et al. 2018),
``intphys2`` (IntPhys 2, Bordes et al. 2025) and ``physical_concepts`` (DeepMind Physical
Concepts, Piloto et al. 2022), each a sub-package holding its ``reader`` (the released layout
read as our records: no Lightning), its ``datamodule`` (the records served to a Trainer) and,
where we write our probes in its layout, its ``export``.

What they share is here: ``reader`` (errors, skipped-input counts, frame sampling, pairing
possible with impossible videos), ``mp4`` (a video read safely), ``cache`` (decoded records
kept on disk), ``datamodule`` (``ExternalDataModule``, the DataModules' base),
``external_pairs`` (what a DataModule tells the evaluation), ``metrics`` (the published
metrics) and ``evaluation`` (them applied to a ``test`` run). The ``export`` command and its
WebDataset format are ``voe_lightning.export``. (The repository's top-level ``benchmarks/``
folder is something else: the package's speed scripts.)"""
