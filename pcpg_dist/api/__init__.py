"""The api layer: what a command does, composed of the runner, tracking and reporting."""
