"""Scoring a run against the ground truth: the metrics of a run's logs
(:mod:`.metrics`), the force sensor's spectra (:mod:`.spectra`) and what the
run's data allow any identifier to know (:mod:`.identifiability`)."""
