"""core/mc."""
