"""mario."""
