"""The external benchmarks (IntPhys, IntPhys 2, DeepMind Physical Concepts): read as our clip and
probe records (folder, mp4 and TFRecord readers and their torch Datasets, one module each, on
``base``; the decoded-record ``cache``) and evaluated by their own published metrics
(``metrics``; ``evaluation`` applies them to a ``test`` run). No Lightning in them: the
DataModules in ``voe_lightning.datamodules`` serve the records to a Trainer. (The top-level ``benchmarks/``
folder is something else: the package's speed scripts.)"""
