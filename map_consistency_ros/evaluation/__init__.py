"""Reproduces the paper's consistency experiment: a labelled map suite from real data, both
methods swept over their parameters, specificity / recall and Pareto frontiers, runtimes."""
