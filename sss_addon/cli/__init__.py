"""sss_addon/cli."""
