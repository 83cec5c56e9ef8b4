"""Online identification of the environment's M_e, B_e and K_e: recursive
least squares and the 3-4-1 neural network, and their wiring."""
