"""The audit of the probes against physics-blind cues: the cues and their tests (``cues``), the
``audit`` command's report of them (``cue_report``) and the calibration of the VOE verdict
against models that follow a cue and have no physics (``calibration``)."""
