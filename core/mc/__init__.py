"""Monte Carlo subsurface scattering: the unified estimator, SPVG adaptive counts,
control variates, the per-pixel history and the processor that ties them together."""
