"""tankctl package."""
