"""The comprehensive reducer station's pure core (GB/T 35089 §7–8): the reducer's kinematics (tooth numbers →
orders of the transmission error per output revolution), the transmission-error evaluation with its orders named,
the starting-torque, no-load-torque and efficiency evaluations, and the discrepancy workflow on the transmission
error. Arrays in, results out; docs/transmission.md derives and explains them."""
