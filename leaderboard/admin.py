"""Admin registrations of the leaderboard app (none yet)."""
