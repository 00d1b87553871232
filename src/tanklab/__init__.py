"""tanklab package."""
