"""Training: the loop, its settings, kernels, optimiser, stopping rule, datasets and densification strategies."""
