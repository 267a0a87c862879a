"""The one parameter schema, its validation and the frozen parameter sets (pure numpy)."""
