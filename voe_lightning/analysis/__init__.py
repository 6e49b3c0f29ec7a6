"""Analyses across runs, the ``analyze`` subcommands' work: relative surprise over training
(``training_curves``, paper Figure 6) and the step VOE emerges (``emergence``), tested runs side
by side (``comparison``), a VRNN-LRU's latents in use (``latent_code``), the untrained null
(``null``) and the training-set-size sweep (``size_sweep``, paper Figure 3). The command line
parses and dispatches to them; benchmarks and experiments import them from here."""
