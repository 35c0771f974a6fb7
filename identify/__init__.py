"""hil.identify: frequency-response estimation, grey-box models and posteriors (emcee)."""
