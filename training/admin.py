"""Admin registrations of the training app (none yet)."""
