"""core/separable."""
