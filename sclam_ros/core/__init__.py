"""The numerical core: SE(2), kinematics, factors, solver, graph, batch estimator, marginals,
parameters and the plain input types. May import: numpy, scipy, yaml and other core modules only."""
