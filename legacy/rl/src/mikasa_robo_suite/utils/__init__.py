"""Old utilities package of the RL release."""
