"""Final renders with splats: engine hooks, the compositor bridge, render state, layers, failures, the panel."""
