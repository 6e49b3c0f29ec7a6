"""The audit of the probes against physics-blind cues: each cue's values and scores of a video
(``video_cues``), the cue audit of probe pairs and its tests (``cues``), the
``audit`` command's report of them (``cue_report``) and the calibration of the VOE verdict
against models that follow a cue and have no physics (``calibration``)."""
