"""What a result can and cannot tell, read-only: uncertainty and identifiability, the optima
left in the DE populations, leave-one-out refits, the hand-angle convention check and where
the calibration holds (scope). Diagnostics never change a result's parameters."""
