"""The simulated bench: physics (ground truth) and instrument simulators speaking the real protocols."""
