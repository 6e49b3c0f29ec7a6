"""The external benchmarks (IntPhys, IntPhys 2, DeepMind Physical Concepts) read as our clip and
probe records: folder, mp4 and TFRecord readers and their torch Datasets, with no Lightning in
them (the DataModules in ``datamodules`` serve them to a Trainer), and the decoded-record cache."""
