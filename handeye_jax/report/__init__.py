"""For people: the printed summary of a calibration and its figures (PNG and SVG)."""
