"""Models of the training app (none yet)."""
