"""A synthetic twin of the rig with known truth: draw or change a truth, synthesize the
observations, render the pictures, simulate a twin folder, and evaluate a calibration on its
held-out targets."""
