"""The studies' computations; their command lines and figures are in ``sss_addon.cli.studies``."""
