"""Runs a training or evaluation job from its database row (on a Celery worker, or inline for
the command line): builds where rollouts run and the hooks (progress, live frames,
checkpoints), hands them to :mod:`training.rl`, and records the outcome through the services."""
