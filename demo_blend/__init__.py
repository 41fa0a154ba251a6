"""Scripts that build the demo scenes deterministically (see ``scenes``)."""
