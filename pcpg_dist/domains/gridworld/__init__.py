"""gridworld."""
