"""The paper's evaluations: baselines (random, inverse CNN, nearest neighbour) and Table 1."""
