"""What a fit minimises: parameter spaces (free, fixed, with a Gaussian prior), the named
residual blocks of each stage's objective, robust losses, and the linearisation at an optimum
(Jacobian, covariance, weak directions)."""
