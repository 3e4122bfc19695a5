"""The fit: settings, plans (what each stage fits), one stage's search for its best optimum
(DE, LM polish, restarts, multi-start refits; the lowest wins), the two-stage pipelines
(calibrate, recalibrate), the warnings, and the result with its file. The only place that
joins the hand–eye problem to the optimisers."""
