"""Old dataset-collector package of the RL release (1.0.0 wheel)."""
