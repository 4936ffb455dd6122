"""Old dataset-collector package of the RL release."""
