"""Sensing: the FS6-120A force sensor, the DSP's force input, and the
kinematic estimator from the encoders; filter design shared by them."""
