"""Readers and writers that turn files (CARMEN logs, g2o graphs, bags) into numpy data."""
