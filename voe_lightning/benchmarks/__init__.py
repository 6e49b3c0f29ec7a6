"""The external benchmarks (IntPhys, DeepMind Physical Concepts) read as our clip and probe
records: folder and TFRecord readers and their torch Datasets, with no Lightning in them (the
DataModules in ``datamodules`` serve them to a Trainer), and the decoded-record cache."""
